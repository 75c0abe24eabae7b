"""The learner process: trains a learned policy from the swarm's own rollouts over Zenoh.

Reads top to bottom: config, counters, the learner loop, its entry point. Joining records into
episodes is swarm.learn.join; weights (de)serialisation swarm.learn.weights; the update
swarm.learn.update.

Data flow of one episode (keys in swarm.net.keys):

- each robot, at the episode's end, puts a `RobotRollout` on `robot/<i>/rollout`: per tick its
  own trajectory payload, the ids it heard, whether its predecessor's hidden-state message
  arrived, its action, log-probability, last reward and the weights version it acted with;
- the world puts an `EpisodeRecord` on `world/episode`: every robot's reward per tick, which
  robots acted in time, the episode's metrics;
- a rollout worker instead puts whole `EpisodeRollout`s on `worker/<k>/episodes`.

The learner joins the first two into an `EpisodeRollout` (the robots' own trajectory messages
are exactly what their receivers heard, so the tick's `View` is rebuilt bit for bit), stacks a
batch of them (`batches`) into the batched trainer's `Rollout`, runs the very same
`swarm.learn.update.update`, checkpoints atomically, and only then publishes the new version
on `learner/weights` (a queryable there serves the current version to late joiners). An update
is acknowledged when its version is published; a SIGKILLed learner resumes from the
checkpoint of the last one.

Stale rollouts: an episode's version is the oldest any of its robots acted with. Episodes more
than `max_staleness` versions behind (when they come or while they wait for a batch) are
dropped, `stale_dropped`; others are used (`stale_used`), each decision weighted by the
truncated importance ratio min(is_clip, pi_now / pi_acted) of the recorded log-probabilities
(swarm.learn.update.backward); fresh episodes weigh exactly 1."""

from __future__ import annotations

import copy
import dataclasses
import logging
import secrets
import sys
import tempfile
import time
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import zenoh

from policies import check_learned, policy_class
from policies.checkpoint import load_checkpoint, save_checkpoint
from swarm.common.report import counted, provenance
from swarm.common.spawn import stops_held
from swarm.learn.config import LearnerConfig, TrainConfig, learner_resume_point
from swarm.learn.curves import CurveLog, read_curve
from swarm.learn.join import join, rollout_of
from swarm.learn.update import update
from swarm.learn.weights import weights_of
from swarm.net.inbox import Inbox, check_free, publisher, tally
from swarm.net.keys import Keys
from swarm.net.learning import EpisodeRecord, EpisodeRollout, RobotRollout
from swarm.net.messages import BIG, K_LSTATUS, BadMessage, pack_record
from swarm.net.zconfig import ZenohOptions, open_session
from swarm.procs.learning.batches import by_seed, fresh, next_batch, take_batch
from swarm.procs.learning.journal import Journal
from swarm.procs.learning.ledger import Settled, Workers
from swarm.procs.learning.watch import RunWatch
from swarm.procs.runconfig import RunConfig, RunRecord
from world.config import ConfigError, WorldConfig

log = logging.getLogger("swarm.learner")


# ------------------------------------------------------------------------------ the learner
@dataclass
class LearnerCounters:
    episodes: int = 0  # joined or received episodes accepted into a batch
    robot_records: int = 0
    world_records: int = 0
    worker_episodes: int = 0
    updates: int = 0
    stale_used: int = 0
    stale_dropped: int = 0
    incomplete: int = 0  # an acting robot's record (or the world's) never came
    rejected: int = 0  # records that do not fit together, are not whole episodes, or were
    # played with weights newer than this learner's (another learner's)
    trained: int = 0  # episodes that went into an update
    received: int = 0  # distinct episodes heard of (swarm episodes + worker episodes)
    lost: int = 0  # heard of by this learner before a stop, not yet in an update (`Journal`)
    late_records: int = 0  # robot or world records of an episode already joined or given up
    bad: int = 0
    rollout_bytes: int = 0
    bad_by_key: dict[str, int] = field(default_factory=dict)


class Learner:
    """One learner of one run: `Learner(...)` checks everything and loads the weights (nothing
    written yet), `open_out()` makes its directory, `run(session, seed, stop)` loops until
    `stop()` is true or it is interrupted."""

    def __init__(self, cfg: WorldConfig, lc: LearnerConfig, tc: TrainConfig,
                 given: Collection[str] | None = None, command: str = "swarm learner") -> None:
        """`given`: the TrainConfig fields the user set (None: every field of `tc` is meant),
        which `--resume` holds against the checkpoint's (see `resumed_train`); `command`: the
        command line that started it, which every checkpoint records."""
        if not lc.out:
            raise ConfigError("the learner needs an output directory (--out DIR)")
        self.cfg, self.lc, self.command = cfg, lc, command
        self.keys = Keys(lc.run_id)
        self.out = Path(lc.out)
        if self.out.exists() and not self.out.is_dir():
            raise ConfigError(f"--out {self.out} exists and is not a directory")
        self.ckpt = self.out / "checkpoint.pt"
        self.curves = CurveLog(self.out)
        self.journal = Journal(self.out / "heard.log")
        self.c = LearnerCounters()
        self.version = self.saved = 0  # saved: the version its checkpoint file holds
        self.workers = Workers()  # each rollout worker's next episode
        self.settled = Settled()  # swarm episodes joined or given up
        self.held = 0  # episodes unsettled at the resumed checkpoint (lost with its process)
        self.seed: int | None = None  # the run's seed its episodes are joined with (`run`)
        check_learned(lc.policy, "the learner")
        cls = policy_class(lc.policy)
        if lc.resume:
            if not self.ckpt.is_file():
                raise ConfigError(f"--resume: {self.ckpt} does not exist (nothing to resume)")
            state = load_checkpoint(self.ckpt).get("learner")
            tc = learner_resume_point(state, tc, given, self.out)
            self.policy = cls(cfg, checkpoint=self.ckpt)
            self.opt = torch.optim.Adam(self.policy.net.parameters(), lr=tc.lr)
            self.opt.load_state_dict(state["optimizer"])
            self.version = self.saved = int(state["version"])
            known = {f.name for f in dataclasses.fields(LearnerCounters)}
            self.c = LearnerCounters(**{k: v for k, v in state["counters"].items() if k in known})
            held = state.get("pending", 0)  # (a checkpoint from before it was kept: 0)
            self.held = held if isinstance(held, int) and 0 <= held <= self.c.received else 0
            self.workers.resume(state.get("workers", {}), str(self.ckpt))
            self.settled.resume(state)
        else:
            if self.ckpt.exists() and not lc.gather_only:
                raise ConfigError(f"{self.out} already holds a learner; pass --resume")
            torch.manual_seed(lc.seed)
            self.policy = cls(cfg, checkpoint=lc.checkpoint) if lc.checkpoint else cls(cfg)
            self.opt = torch.optim.Adam(self.policy.net.parameters(), lr=tc.lr)
        torch.set_num_threads(tc.threads)
        self.tc = tc
        self.pending: dict[int, dict[str, Any]] = {}  # ep -> {"world": rec, "robots": {}, "t": s}
        self.ready: list[EpisodeRollout] = []
        self.origin = 1 + secrets.randbelow(BIG)  # this process's weights (Weights.origin)
        self.weights_payload = weights_of(self.policy, self.version, self.origin).pack()
        self.curve: list[float] = []  # the dashboard's sparkline: elratio per update
        self.t0, self.elapsed0 = time.monotonic(), 0.0  # (elapsed0: the run's, before a resume)
        self._last_status = 0.0
        self.inbox: Inbox | None = None  # (its drops go in the status)
        self.last_row: dict[str, Any] = {}
        self.ended = ""  # why the run is over, when its end stopped the learner (`RunWatch`)

    def open_out(self) -> None:
        """Make the output directory (only now: a learner that fails its checks leaves nothing
        behind) and start the curve, or, resumed, cut it back to the checkpoint and reload the
        sparkline and last row from it."""
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=self.out):  # permission bits do not say it for root
                pass
        except OSError as exc:
            raise ConfigError(f"--out {self.out} is not writable ({exc.strerror or exc})") from None
        if self.lc.resume:
            self.curves.resume(self.version)
            try:
                cols = read_curve(self.curves.csv)
            except (ConfigError, OSError, ValueError):  # no curve, or no row yet
                cols = {}
            if cols:
                self.curve = cols["elratio"][-40:]
                self.last_row = {k: cols[k][-1] for k in ("elratio", "reward", "loss")
                                 if cols.get(k)}
                self.elapsed0 = cols["elapsed_s"][-1] if cols.get("elapsed_s") else 0.0
            log.warning("learner resumed at version %d", self.version)
        elif not self.lc.gather_only:
            self.curves.start()
        if not self.lc.gather_only:  # (one never updates: nothing to lose, nor a checkpoint)
            if self.lc.resume:  # unsettled at the checkpoint, and heard of after it
                past = self.journal.past(self.c.received)
                self.c.received += past.count
                # what the stopped learner heard of is settled (trained, or counted here): a
                # late record of it is late, not a new episode received a second time, and a
                # restarted worker goes on after its last episode
                self.settled.heard_before(past.swarm)
                for k, ep in past.workers.items():
                    self.workers.heard(k, ep)
                if lost := self.held + past.count:
                    self.c.lost += lost
                    log.warning("learner: %s heard of by the stopped learner after its last "
                                "update (version %d) never trained on: counted lost",
                                counted(lost, "episode"), self.version)
            self.journal.open(fresh=not self.lc.resume)

    # --- network ----------------------------------------------------------------------------
    def _declare(self, session: zenoh.Session) -> Inbox:
        self.session = session
        k, s = self.keys, session
        self.weights_pub = publisher(s, k.weights)
        self.status_pub = publisher(s, k.learner_status)
        self.inbox = Inbox(s)
        return (self.inbox.subscribe(k.rollout("*"), "robot").subscribe(k.episode, "world")
                .subscribe(k.worker_episodes("*"), "worker")
                .queryable(k.weights, lambda: self.weights_payload)
                .queryable(k.learner_config, self.record)
                .subscribe(k.end, "end").liveliness(k.alive_world, "world")
                .token(k.alive_learner))

    def record(self) -> bytes:
        """The run record rollout workers fetch: world, policy, model and train settings."""
        return RunRecord(self.cfg, RunConfig(run_id=self.lc.run_id, policy=self.lc.policy),
                         learner=dataclasses.asdict(self.lc), train=dataclasses.asdict(self.tc),
                         model=dataclasses.asdict(self.policy.model_cfg),
                         version=self.version, workers=self.workers.next).pack()

    def _bad(self, key: str, why: str) -> None:
        self.c.bad += 1
        if tally(self.c.bad_by_key, key):
            log.warning("learner dropped bad payload on %s: %s", key, why)

    # --- gathering --------------------------------------------------------------------------
    def handle(self, kind: str, key: str, payload: bytes) -> None:
        self.c.rollout_bytes += len(payload)
        try:
            if kind == "robot":
                rr = RobotRollout.unpack(payload, self.cfg)
                if Keys.robot_of(key) != rr.robot:
                    raise BadMessage(f"robot id {rr.robot} does not match key")
                slot = self._slot(rr.ep)
                if slot is not None and rr.robot in slot["robots"]:  # the first one stands
                    raise BadMessage(f"a second record of robot {rr.robot}, episode {rr.ep}")
                if slot is not None:  # (else counted late: each record in one counter)
                    self.c.robot_records += 1
                    slot["robots"][rr.robot] = rr
            elif kind == "world":
                wr = EpisodeRecord.unpack(payload, self.cfg)
                slot = self._slot(wr.ep)
                if slot is not None and "world" in slot:  # the first one stands
                    raise BadMessage(f"a second world record of episode {wr.ep}")
                if slot is not None:  # (else counted late)
                    self.c.world_records += 1
                    slot["world"], slot["t"] = wr, time.monotonic()
            else:
                er = EpisodeRollout.unpack(payload, self.cfg)
                worker = self.workers.check(er, self.tc.train_seed_offset + self.tc.seed + 1,
                                            Keys.worker_of(key))
                self.c.worker_episodes += 1
                self._heard(er.ep, worker)
                self._accept(er)
        except (BadMessage, ValueError) as exc:
            self._bad(key, str(exc))

    def _slot(self, ep: int) -> dict[str, Any] | None:
        """The joining slot of swarm episode `ep` (a new episode counts as received); None
        for an episode already joined or given up (its late record is counted, not kept)."""
        if ep in self.pending:
            return self.pending[ep]
        if ep in self.settled:
            self.c.late_records += 1
            self.settled.late(ep)
            return None
        self._heard(ep)
        self.pending[ep] = {"robots": {}, "first": time.monotonic()}
        return self.pending[ep]

    def _heard(self, ep: int, worker: int | None = None) -> None:
        self.c.received += 1
        self.journal.heard(self.c.received, ep, worker)

    def _close(self, ep: int) -> None:
        del self.pending[ep]
        self.settled.add(ep)

    def _accept(self, er: EpisodeRollout) -> None:
        if er.actions.shape[0] != self.cfg.horizon:  # a batch stacks whole episodes only
            self.c.rejected += 1
            log.warning("learner dropped episode %d: %d of %d ticks", er.ep,
                        er.actions.shape[0], self.cfg.horizon)
            return
        if er.version > self.version:  # weights this learner never made: another's (one it
            self.c.rejected += 1  # replaced, or a forger's); their log-probabilities are not ours
            if self.c.rejected & (self.c.rejected - 1) == 0:  # (the 1st, 2nd, 4th, ...)
                log.warning("learner dropped episode %d: played with weights v%d, newer than its "
                            "own v%d (another learner's)", er.ep, er.version, self.version)
            return
        if self.version - er.version > self.lc.max_staleness:
            self.c.stale_dropped += 1
            return
        if er.version < self.version:
            self.c.stale_used += 1
        self.c.episodes += 1
        if not self.lc.gather_only:
            self.ready.append(er)

    def join_ready(self, seed: int, force: bool = False) -> bool:
        """Join every pending episode whose records are all in (or whose wait timed out); True
        when one was settled."""
        now = time.monotonic()
        settled = False
        for ep in sorted(self.pending):
            slot = self.pending[ep]
            wr = slot.get("world")
            if wr is None:  # robots' records whose world record never came: give up on them
                if force or now - slot["first"] > 4 * self.lc.join_timeout:
                    self._close(ep)
                    settled = True
                    self.c.incomplete += 1
                    log.warning("learner dropped episode %d: no world record", ep)
                continue
            acted = set(np.flatnonzero(wr.acted.any(0)).tolist())
            complete = acted <= set(slot["robots"])
            if not complete and not force and now - slot["t"] < self.lc.join_timeout:
                continue
            self._close(ep)
            settled = True
            try:
                self._accept(join(self.cfg, seed, wr, slot["robots"]))
            except BadMessage as exc:
                if complete:
                    self.c.rejected += 1
                else:
                    self.c.incomplete += 1
                log.warning("learner dropped episode %d: %s", ep, exc)
        return settled

    # --- learning ---------------------------------------------------------------------------
    def _batch(self) -> list[EpisodeRollout] | None:
        """The next batch (`batches.take_batch`); the episodes it leaves out, counted."""
        batch, self.ready, stale, blocked = take_batch(
            self.ready, self.tc.batch, by_seed(self.policy), self.version, self.lc.max_staleness)
        self._left_ready(stale, "stale_dropped")
        self._left_ready(blocked, "rejected")
        if blocked:
            log.warning("learner dropped %d episode(s) no batch takes (undecided ticks)", blocked)
        return batch

    def _left_ready(self, n: int, counter: str) -> None:  # (`episodes`: trained or ready)
        setattr(self.c, counter, getattr(self.c, counter) + n)
        self.c.episodes -= n

    def maybe_update(self) -> bool:
        batch = self._batch()
        if batch is None:
            return False
        t0 = time.perf_counter()
        net_before = copy.deepcopy(self.policy.net.state_dict())
        opt_before = copy.deepcopy(self.opt.state_dict())
        torch.set_flush_denormal(True)
        try:
            roll = rollout_of(batch, self.policy, self.version)
            parts = update(self.policy, self.opt, roll, self.tc)
        except (ValueError, IndexError, RuntimeError) as exc:  # (every check passed: a defect)
            self.policy.net.load_state_dict(net_before)  # (PPO steps each epoch: none kept)
            self.opt.load_state_dict(opt_before)
            self._left_ready(len(batch), "rejected")
            log.error("learner dropped a batch of %d episodes it could not train on: %s",
                      len(batch), str(exc)[:200])
            return False
        finally:
            torch.set_flush_denormal(False)
        self.c.trained += len(batch)
        self.version += 1
        self.c.updates += 1
        m = roll.metrics
        row = {"update": self.version, "epoch": 0, "episodes": self.c.episodes,
               "n_dynamic": self.cfg.n_active_dynamic, "elratio": float(m.elratio.mean()),
               "success": float(m.success.mean()), "reward": float(m.reward.mean()),
               "collisions": float(m.collisions.mean()),
               "block_collisions": float(m.block_collisions.mean()), **parts,
               "episodes_per_s": len(batch) / max(time.perf_counter() - t0, 1e-9),
               "elapsed_s": self.elapsed0 + time.monotonic() - self.t0}
        self.save()  # acknowledged only once durable ...
        self.weights_payload = weights_of(self.policy, self.version, self.origin).pack()
        self.weights_pub.put(self.weights_payload)  # ... then published
        self.curves.append(row, algo=self.tc.algo, version=self.version,
                           episode_ids=[e.ep for e in batch], versions=[e.version for e in batch])
        self.curve.append(row["elratio"])
        self.last_row = row
        log.info("learner: version %d, elratio %.3f", self.version, row["elratio"])
        self.status(force=True)
        return True

    def save(self) -> None:
        payload = self.policy.payload({"command": self.command, "version": self.version,
                                       "episodes": self.c.episodes, "run_id": self.lc.run_id,
                                       "provenance": provenance()})
        payload["learner"] = {"version": self.version, "optimizer": self.opt.state_dict(),
                              "train": dataclasses.asdict(self.tc),
                              "counters": dataclasses.asdict(self.c),
                              "pending": self.accounting()["pending"],  # (lost, if it stops)
                              "workers": dict(self.workers.next),
                              **self.settled.state(self.pending),
                              **({} if self.seed is None else {"seed": self.seed})}
        with stops_held():  # (a Ctrl-C between the file's rename and this line: the stop line
            save_checkpoint(self.ckpt, payload)  # named the version before the file's)
            self.saved = self.version  # (one during the update: the last file stands)
            self.journal.clear()

    def accounting(self) -> dict[str, int]:
        """Where every episode heard of is: received = trained + pending + stale_dropped +
        incomplete + rejected + lost, exactly (pending: joining, or joined and waiting for a
        batch; in a gather-only learner every accepted episode stays pending; lost: held by
        this learner when it stopped before an update, counted when it resumed)."""
        # (a gather-only learner's accepted episodes; in one that trains, those its stopped self
        # had ready for a batch are in `lost`, though still in `episodes`, the accepted count)
        gathered = self.c.episodes - self.c.trained if self.lc.gather_only else 0
        return {"received": self.c.received, "trained": self.c.trained,
                "pending": len(self.pending) + len(self.ready) + gathered,
                "stale_dropped": self.c.stale_dropped, "incomplete": self.c.incomplete,
                "rejected": self.c.rejected, "lost": self.c.lost}

    def finish(self, inbox: Inbox, seed: int, watch: RunWatch | None = None,
               grace: float = 0.3) -> dict[str, Any]:
        """On the way out: take in what is still queued (the world's own events to `watch`, as
        in the loop: they are no rollouts), settle every joining episode (a partial batch is
        never trained on: it stays pending), publish the final status."""
        deadline = time.monotonic() + grace
        while (ev := inbox.next(deadline - time.monotonic())) is not None:
            if watch is None or not watch.see(ev):
                self.handle(ev.kind, ev.key, ev.payload or b"")
        self.join_ready(seed, force=True)
        return self.status(force=True)  # type: ignore[return-value]

    def status(self, force: bool = False) -> dict[str, Any] | None:
        """Publish the status record when it is due (or `force`d); returns it, None if not due."""
        now = time.monotonic()
        if not force and now - self._last_status < self.lc.status_every:
            return None
        self._last_status = now
        rec = {"version": self.version, "origin": self.origin,  # (a fresh learner: versions anew)
               "episodes": self.c.episodes, "updates": self.c.updates,
               "pending": len(self.pending), "ready": len(self.ready),
               "stale_used": self.c.stale_used, "stale_dropped": self.c.stale_dropped,
               "incomplete": self.c.incomplete, "bad": self.c.bad,
               "late_records": self.c.late_records, **(self.inbox.dropped if self.inbox else {}),
               "accounting": self.accounting(),
               # what a lockstep world (swarm.net.learning.LearnerGate) waits for
               "last_closed": self.settled.last,
               "update_due": next_batch(fresh(self.ready, self.version, self.lc.max_staleness),
                                        self.tc.batch, by_seed(self.policy)) is not None,
               "worker_episodes": self.c.worker_episodes,
               "rollout_bytes": self.c.rollout_bytes,
               "rollout_bytes_per_s": self.c.rollout_bytes / max(now - self.t0, 1e-9),
               "curve": self.curve[-40:], "last": {k: self.last_row.get(k) for k in
                                                   ("elratio", "reward", "loss")},
               "wall": time.time()}
        self.status_pub.put(pack_record(K_LSTATUS, rec))
        return rec

    def run(self, session: zenoh.Session, seed: int, stop: Any = lambda: False
            ) -> dict[str, Any]:
        inbox = self._declare(session)
        self.seed = seed
        watch = RunWatch(session, self.keys, self.cfg, self.lc.policy, seed)
        try:
            self.weights_pub.put(self.weights_payload)  # late joiners also query it
            while not stop() and not watch.ended:  # (the run's end: its last episodes are in)
                ev = inbox.next(0.05)
                if ev is not None and not watch.see(ev):
                    self.handle(ev.kind, ev.key, ev.payload or b"")
                settled = self.join_ready(seed)
                updated = self.maybe_update()  # (an update publishes its status itself)
                self.status(force=settled and not updated)  # a settled episode is told at once
            self.ended = watch.ended
            return self.finish(inbox, seed, watch)
        except KeyboardInterrupt:  # Ctrl-C, or SIGTERM (the supervisor stopping or gone)
            return self.finish(inbox, seed, watch)
        finally:
            inbox.close()
            self.journal.close()


def main(cfg: WorldConfig, lc: LearnerConfig, tc: TrainConfig, zopts: ZenohOptions,
         seed: int, stop: Any = lambda: False, given: Collection[str] | None = None,
         command: str = "swarm learner") -> dict[str, Any]:
    """Check and load (before anything is opened or written), open a session, make the output
    directory and learn until the run ends, it is interrupted or `stop()`; returns the last
    status. `given`, `command`: see `Learner`."""
    learner = Learner(cfg, lc, tc, given, command)
    with open_session(zopts) as session:  # (two learners would publish two lines of weights)
        check_free(session, Keys(lc.run_id).alive_learner, f"a learner of run {lc.run_id}", 1.0)
        learner.open_out()
        does = "counts the run's episodes (--gather-only: no update)" if lc.gather_only else \
            "trains on the run's episodes"
        print(f"swarm learner: run {lc.run_id}, {lc.policy}, writing {lc.out}; it {does} until "
              "the run ends (Ctrl-C stops it)", file=sys.stderr, flush=True)
        try:  # (`run` closes its journal; this, if `run` never got so far)
            status = learner.run(session, seed, stop)
        finally:
            learner.journal.close()
    # where its weights are, however it ended (its checkpoint is written, atomically, at
    # every update); a learner fed by rollout workers alone ends only by Ctrl-C
    kept = f"version {learner.saved} in {learner.ckpt}" if learner.ckpt.is_file() else \
        "--gather-only: no checkpoint written" if lc.gather_only else \
        f"no update (fewer than {learner.tc.batch} episodes): no checkpoint written"
    why = f"run {lc.run_id} ended ({learner.ended})" if learner.ended else "stopped"
    print(f"swarm learner: {why}; {kept}", file=sys.stderr, flush=True)
    return status
