"""The learner process: trains a learned policy from the swarm's own rollouts over Zenoh.

Reads top to bottom: conversions between the trainer's `Rollout` and the per-episode wire
records, versioned weights, the joiner, the learner loop, its entry point.

Data flow of one episode (keys in swarm.keys):

- each robot, at the episode's end, puts a `RobotRollout` on `robot/<i>/rollout`: per tick its
  own trajectory payload, the ids it heard, whether its predecessor's hidden-state message
  arrived, its action, log-probability, last reward and the weights version it acted with;
- the world puts an `EpisodeRecord` on `world/episode`: every robot's reward per tick, which
  robots acted in time, the episode's metrics;
- a rollout worker instead puts whole `EpisodeRollout`s on `rollout/episode`.

The learner joins the first two into an `EpisodeRollout` (the robots' own trajectory messages
are exactly what their receivers heard, so the tick's `View` is rebuilt bit for bit), stacks
`batch` of them into the batched trainer's `Rollout`, runs the very same `swarm.train.update`,
checkpoints atomically, and only then publishes the new version on `learner/weights` (a
queryable there serves the current version to late joiners). An update is acknowledged when
its version is published; a SIGKILLed learner resumes from the checkpoint of the last one.

Stale rollouts: an episode's version is the oldest any of its robots acted with. Episodes more
than `max_staleness` versions behind are dropped and counted (`stale_dropped`); others are used
as if on-policy (`stale_used` counts them): REINFORCE has no correction for the lag, and with
robots adopting weights at episode boundaries the lag is at most one version in practice.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import logging
import queue
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import zenoh

from policies import policy_class
from policies.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from policies.learned import LearnedPolicy
from swarm.keys import Keys
from swarm.messages import (
    K_LSTATUS,
    METRIC_NAMES,
    BadMessage,
    EpisodeRecord,
    EpisodeRollout,
    RobotRollout,
    Traj,
    Weights,
    pack_record,
)
from swarm.train import CURVE_FIELDS, Rollout, update
from swarm.train_config import TrainConfig
from swarm.zconfig import ZenohOptions
from world import core
from world.config import ConfigError, WorldConfig, from_dict, to_dict
from world.decentral import TrajMessages, View, remember

log = logging.getLogger("swarm.learner")


# ------------------------------------------------------------------------------- conversions
def episodes_of(roll: Rollout, version: int) -> list[EpisodeRollout]:
    """The batched trainer's rollout as one `EpisodeRollout` per group (rollout workers)."""
    out = []
    st = lambda f: np.stack([f(v) for v in roll.views])  # noqa: E731
    pos, vis = st(lambda v: v.msgs.pos), st(lambda v: v.msgs.visited)
    rec, patch = st(lambda v: v.msgs.recent), st(lambda v: v.msgs.patch)
    present, hears = st(lambda v: v.msgs.present), st(lambda v: v.hears)
    recv, last = st(lambda v: v.receivers), st(lambda v: v.last_reward)
    ok = st(lambda v: v.chain_ok if v.chain_ok is not None else np.ones_like(v.receivers))
    acts = np.stack(roll.actions)
    m = roll.metrics
    for g, ep in enumerate(roll.views[0].episodes):
        out.append(EpisodeRollout(
            ep=int(ep), seed=int(roll.views[0].seed), version=version, pos=pos[:, g],
            visited=vis[:, g], recent=rec[:, g], patch=patch[:, g], present=present[:, g],
            hears=hears[:, g], receivers=recv[:, g], chain_ok=ok[:, g],
            last_reward=last[:, g].astype(np.float32), actions=acts[:, g],
            reward=roll.reward[:, g].astype(np.float32),
            metrics={k: float(getattr(m, k)[g]) for k in METRIC_NAMES},
            logp=None if roll.logp is None else roll.logp[:, g].astype(np.float32)))
    return out


def rollout_of(eps: list[EpisodeRollout], policy: LearnedPolicy,
               version: int | None = None) -> Rollout:
    """Stack episodes (all of the same length) into the batched trainer's `Rollout`; features and
    the baseline values b(s) are computed here with the learner's current weights. Episodes that
    carry their acting log-probabilities and were acted by a version older than `version` are
    marked stale (the update weighs them by truncated importance ratios)."""
    if not eps:
        raise ValueError("no episodes")
    ticks = eps[0].actions.shape[0]
    if any(e.actions.shape[0] != ticks for e in eps):
        raise ValueError("episodes of different lengths")
    st = lambda name, t: np.stack([getattr(e, name)[t] for e in eps])  # noqa: E731
    views = [View(seed=eps[0].seed, episodes=np.array([e.ep for e in eps], dtype=np.int64),
                  tick=t, msgs=TrajMessages(st("pos", t), st("visited", t), st("recent", t),
                                            st("patch", t), st("present", t)),
                  hears=st("hears", t), receivers=st("receivers", t),
                  last_reward=st("last_reward", t), chain_ok=st("chain_ok", t))
             for t in range(ticks)]
    if policy.features.memory:  # the team memory each robot folded tick by tick
        remember(views, policy.cfg)
    actions, inputs, values = [], [], []
    for t, view in enumerate(views):
        act = st("actions", t)
        feats = policy.features(view)
        with torch.no_grad():
            ev = policy.evaluate([view], [act], [feats])
        value = np.zeros(act.shape, dtype=np.float32)
        value[ev.group, ev.robot] = ev.value.numpy()
        actions.append(act)
        inputs.append(feats)
        values.append(value)
    reward = np.stack([e.reward for e in eps], axis=1)  # [T, B, N]
    metrics = core.EpisodeMetrics(**{k: np.array([e.metrics[k] for e in eps])
                                     for k in METRIC_NAMES})
    logp = stale = None
    if all(e.logp is not None for e in eps):
        logp = np.stack([e.logp for e in eps], axis=1)  # type: ignore[misc]
        stale = np.array([version is not None and e.version < version for e in eps])
    return Rollout(views, actions, inputs, np.stack(values), reward, metrics, logp, stale)


def join(cfg: WorldConfig, seed: int, world: EpisodeRecord,
         robots: dict[int, RobotRollout]) -> EpisodeRollout:
    """The swarm's records of one episode as an `EpisodeRollout`; BadMessage when incomplete
    (a robot that acted sent no record, or a heard message is missing)."""
    ticks, n = world.reward.shape
    out = EpisodeRollout(
        ep=world.ep, seed=seed, version=0, pos=np.zeros((ticks, n, 2), np.int64),
        visited=np.zeros((ticks, n, cfg.cells), bool),
        recent=np.full((ticks, n, cfg.recent_len), -1, np.int64),
        patch=np.zeros((ticks, n, cfg.vision, cfg.vision), np.uint8),
        present=np.zeros((ticks, n), bool), hears=np.zeros((ticks, n, n), bool),
        receivers=np.zeros((ticks, n), bool), chain_ok=np.ones((ticks, n), bool),
        last_reward=np.zeros((ticks, n), np.float32), actions=np.zeros((ticks, n), np.int64),
        reward=world.reward.astype(np.float32), metrics=dict(world.metrics),
        logp=np.zeros((ticks, n), np.float32))
    versions = []
    bit = 1 << np.arange(n)
    for i, rr in robots.items():
        if rr.ep != world.ep or len(rr.ticks) > ticks:
            raise BadMessage(f"robot {i}'s record does not fit episode {world.ep}")
        for traj_bytes, heard, chain_ok, action, logp, last_reward, version in rr.ticks:
            tr = Traj.unpack(traj_bytes, cfg)
            t = tr.t
            if tr.robot != i or tr.ep != world.ep or t >= ticks:
                raise BadMessage(f"robot {i}'s tick record names robot {tr.robot} tick {t}")
            out.pos[t, i] = (tr.y, tr.x)
            out.visited[t, i] = tr.visited_bits(cfg.cells)
            rec = tr.recent[-cfg.recent_len:]
            out.recent[t, i, cfg.recent_len - len(rec):] = rec
            out.patch[t, i] = np.frombuffer(tr.patch, np.uint8).reshape(cfg.vision, -1)
            out.present[t, i] = True
            out.hears[t, i] = (heard & bit) != 0
            out.chain_ok[t, i] = chain_ok
            out.actions[t, i] = action
            out.logp[t, i] = min(logp, 0.0)  # type: ignore[index]
            out.last_reward[t, i] = last_reward
            out.receivers[t, i] = bool(world.acted[t, i])
            versions.append(version)
    missing = world.acted & ~out.present
    if missing.any():
        t, i = map(int, np.argwhere(missing)[0])
        raise BadMessage(f"episode {world.ep}: robot {i} acted at tick {t} but sent no record")
    if (out.hears & ~out.present[:, None, :]).any():
        raise BadMessage(f"episode {world.ep}: a heard trajectory message is missing")
    out.receivers &= out.present
    out.version = min(versions) if versions else 0
    return out


# ----------------------------------------------------------------------------------- weights
def weights_of(policy: LearnedPolicy, version: int) -> Weights:
    return Weights(policy.name, version, dataclasses.asdict(policy.model_cfg),
                   {k: v.detach().numpy().astype(np.float32)
                    for k, v in policy.net.state_dict().items()})


def adopt(policy: LearnedPolicy, w: Weights) -> None:
    """Load `w` into `policy` (see `check_weights`; the policy is unchanged when they don't fit)."""
    check_weights(policy, w)
    policy.net.load_state_dict({k: torch.from_numpy(v) for k, v in w.tensors.items()})


def check_weights(policy: LearnedPolicy, w: Weights) -> None:
    """A one-line BadMessage if `w` is for another policy or network, or carries tensors of the
    wrong shape or non-finite values."""
    if w.policy != policy.name:
        raise BadMessage(f"weights v{w.version} are for {w.policy!r}, not {policy.name!r}")
    ours = dataclasses.asdict(policy.model_cfg)
    if {k: w.model.get(k) for k in ours} != ours:
        raise BadMessage(f"weights v{w.version} are for another {policy.name} network "
                         f"({w.model})")
    state = policy.net.state_dict()
    if set(w.tensors) != set(state):
        odd = sorted(set(w.tensors) ^ set(state))[:3]
        raise BadMessage(f"weights v{w.version} have tensors {odd} that do not fit")
    for k, v in state.items():
        if tuple(w.tensors[k].shape) != tuple(v.shape):
            raise BadMessage(f"weights v{w.version}: {k} has shape {tuple(w.tensors[k].shape)}, "
                             f"expected {tuple(v.shape)}")
        if not np.isfinite(w.tensors[k]).all():
            raise BadMessage(f"weights v{w.version}: {k} is not finite")


# ------------------------------------------------------------------------------ the learner
@dataclass
class LearnerConfig:
    """What a learner does (TOML table `[learner]`; the loss settings come from `[train]`)."""

    run_id: str = "run"
    """The run whose rollouts it gathers."""
    policy: str = "commattn"
    """Learned policy trained."""
    checkpoint: str | None = None
    """Initial weights (a policy checkpoint); without one, fresh weights from `seed`."""
    out: str | None = None
    """Directory of the learner's checkpoint.pt, curve.csv and log.jsonl (required)."""
    resume: bool = False
    """Continue from OUT/checkpoint.pt (version, optimizer and counters)."""
    max_staleness: int = 1
    """Use episodes at most this many versions behind the current one; drop older ones."""
    join_timeout: float = 5.0
    """Seconds after the world's episode record to wait for the robots' records."""
    gather_only: bool = False
    """Gather and count episodes without updating (rollout benchmarks)."""
    status_every: float = 0.5
    """Seconds between status records on learner/status."""
    seed: int = 0
    """Seed of fresh initial weights."""


@dataclass
class LearnerCounters:
    episodes: int = 0  # joined or received episodes accepted into a batch
    robot_records: int = 0
    world_records: int = 0
    worker_episodes: int = 0
    updates: int = 0
    stale_used: int = 0
    stale_dropped: int = 0
    incomplete: int = 0
    bad: int = 0
    rollout_bytes: int = 0
    bad_by_key: dict[str, int] = field(default_factory=dict)


class Learner:
    """One learner of one run; `run(stop)` loops until `stop()` is true or it is interrupted."""

    def __init__(self, cfg: WorldConfig, lc: LearnerConfig, tc: TrainConfig,
                 session: zenoh.Session) -> None:
        if not lc.out:
            raise ConfigError("the learner needs an output directory (--out DIR)")
        self.cfg, self.lc, self.session = cfg, lc, session
        self.keys = Keys(lc.run_id)
        self.out = Path(lc.out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.ckpt = self.out / "checkpoint.pt"
        self.c = LearnerCounters()
        self.version = 0
        torch.set_num_threads(tc.threads)
        cls = policy_class(lc.policy)
        if not cls.learned:
            raise ConfigError(f"policy {lc.policy!r} is not a learned policy")
        if lc.resume and self.ckpt.exists():
            data = load_checkpoint(self.ckpt)
            state = data.get("learner")
            if state is None:
                raise CheckpointError(f"{self.ckpt} holds no learner state; cannot resume")
            self.policy = cls(cfg, checkpoint=self.ckpt)
            tc = from_dict(TrainConfig, state["train"], where="checkpoint train config")
            self.opt = torch.optim.Adam(self.policy.net.parameters(), lr=tc.lr)
            self.opt.load_state_dict(state["optimizer"])
            self.version = int(state["version"])
            known = {f.name for f in dataclasses.fields(LearnerCounters)}
            self.c = LearnerCounters(**{k: v for k, v in state["counters"].items() if k in known})
            from swarm.train import _truncate

            _truncate(self.out / "curve.csv", self.version, is_csv=True)
            _truncate(self.out / "log.jsonl", self.version, is_csv=False)
            log.warning("learner resumed at version %d", self.version)
        else:
            if self.ckpt.exists() and not lc.gather_only:
                raise ConfigError(f"{self.out} already holds a learner; pass --resume")
            torch.manual_seed(lc.seed)
            self.policy = cls(cfg, checkpoint=lc.checkpoint) if lc.checkpoint else cls(cfg)
            self.opt = torch.optim.Adam(self.policy.net.parameters(), lr=tc.lr)
            if not lc.gather_only:
                (self.out / "curve.csv").write_text(",".join(CURVE_FIELDS) + "\n")
                (self.out / "log.jsonl").write_text("")
        self.tc = tc
        self.q: queue.Queue[tuple[str, str, bytes]] = queue.Queue()
        self.pending: dict[int, dict[str, Any]] = {}  # ep -> {"world": rec, "robots": {}, "t": s}
        self.ready: list[EpisodeRollout] = []
        self.weights_payload = weights_of(self.policy, self.version).pack()
        self.curve: list[float] = []
        self.t0 = time.monotonic()
        self._last_status = 0.0
        self.last_row: dict[str, Any] = {}

    # --- network ----------------------------------------------------------------------------
    def _declare(self) -> list[Any]:
        k, q, s = self.keys, self.q, self.session
        sub = lambda key, kind: s.declare_subscriber(  # noqa: E731
            key, lambda smp: q.put((kind, str(smp.key_expr), smp.payload.to_bytes())))
        self.weights_pub = s.declare_publisher(k.weights)
        self.status_pub = s.declare_publisher(k.learner_status)
        return [sub(k.rollout("*"), "robot"), sub(k.episode, "world"),
                sub(k.worker_episodes, "worker"),
                s.declare_queryable(k.weights, self._serve_weights),
                s.declare_queryable(k.learner_config, self._serve_config),
                s.liveliness().declare_token(k.alive_learner)]

    def _serve_weights(self, query: zenoh.Query) -> None:
        query.reply(self.keys.weights, self.weights_payload)

    def _serve_config(self, query: zenoh.Query) -> None:
        import msgpack

        rec = {"world": to_dict(self.cfg), "policy": self.lc.policy,
               "model": dataclasses.asdict(self.policy.model_cfg),
               "train": dataclasses.asdict(self.tc), "version": self.version}
        query.reply(self.keys.learner_config, msgpack.packb(rec, use_bin_type=True))

    def _bad(self, key: str, why: str) -> None:
        self.c.bad += 1
        self.c.bad_by_key[key] = self.c.bad_by_key.get(key, 0) + 1
        log.warning("learner dropped bad payload on %s: %s", key, why)

    # --- gathering --------------------------------------------------------------------------
    def handle(self, kind: str, key: str, payload: bytes) -> None:
        self.c.rollout_bytes += len(payload)
        try:
            if kind == "robot":
                rr = RobotRollout.unpack(payload, self.cfg)
                if Keys.robot_of(key) != rr.robot:
                    raise BadMessage(f"robot id {rr.robot} does not match key")
                self.c.robot_records += 1
                slot = self.pending.setdefault(rr.ep, {"robots": {}, "first": time.monotonic()})
                slot["robots"][rr.robot] = rr
            elif kind == "world":
                wr = EpisodeRecord.unpack(payload, self.cfg)
                self.c.world_records += 1
                slot = self.pending.setdefault(wr.ep, {"robots": {}, "first": time.monotonic()})
                slot["world"], slot["t"] = wr, time.monotonic()
            else:
                er = EpisodeRollout.unpack(payload, self.cfg)
                self.c.worker_episodes += 1
                self._accept(er)
        except (BadMessage, ValueError) as exc:
            self._bad(key, str(exc))

    def _accept(self, er: EpisodeRollout) -> None:
        if er.actions.shape[0] != self.cfg.horizon:  # a batch stacks whole episodes only
            self.c.incomplete += 1
            log.warning("learner dropped episode %d: %d of %d ticks", er.ep,
                        er.actions.shape[0], self.cfg.horizon)
            return
        if self.version - er.version > self.lc.max_staleness:
            self.c.stale_dropped += 1
            return
        if er.version < self.version:
            self.c.stale_used += 1
        self.c.episodes += 1
        if not self.lc.gather_only:
            self.ready.append(er)

    def join_ready(self, seed: int, force: bool = False) -> None:
        """Join every pending episode whose records are all in (or whose wait timed out)."""
        now = time.monotonic()
        for ep in sorted(self.pending):
            slot = self.pending[ep]
            wr = slot.get("world")
            if wr is None:  # robots' records whose world record never came: give up on them
                if now - slot["first"] > 4 * self.lc.join_timeout:
                    del self.pending[ep]
                    self.c.incomplete += 1
                    log.warning("learner dropped episode %d: no world record", ep)
                continue
            acted = set(np.flatnonzero(wr.acted.any(0)).tolist())
            complete = acted <= set(slot["robots"])
            if not complete and not force and now - slot["t"] < self.lc.join_timeout:
                continue
            del self.pending[ep]
            try:
                self._accept(join(self.cfg, seed, wr, slot["robots"]))
            except BadMessage as exc:
                self.c.incomplete += 1
                log.warning("learner dropped episode %d: %s", ep, exc)

    # --- learning ---------------------------------------------------------------------------
    def maybe_update(self) -> bool:
        if self.lc.gather_only or len(self.ready) < self.tc.batch:
            return False
        batch, self.ready = self.ready[:self.tc.batch], self.ready[self.tc.batch:]
        t0 = time.perf_counter()
        roll = rollout_of(batch, self.policy, self.version)
        torch.set_flush_denormal(True)
        try:
            parts = update(self.policy, self.opt, roll, self.tc)
        finally:
            torch.set_flush_denormal(False)
        self.version += 1
        self.c.updates += 1
        m = roll.metrics
        row = {"update": self.version, "epoch": 0, "episodes": self.c.episodes,
               "n_dynamic": self.cfg.n_active_dynamic, "elratio": float(m.elratio.mean()),
               "success": float(m.success.mean()), "reward": float(m.reward.mean()),
               "collisions": float(m.collisions.mean()),
               "block_collisions": float(m.block_collisions.mean()), **parts,
               "episodes_per_s": len(batch) / max(time.perf_counter() - t0, 1e-9),
               "elapsed_s": time.monotonic() - self.t0}
        self.save()  # acknowledged only once durable ...
        self.weights_payload = weights_of(self.policy, self.version).pack()
        self.weights_pub.put(self.weights_payload)  # ... then published
        with (self.out / "curve.csv").open("a") as fh:
            buf = io.StringIO()
            csv.writer(buf).writerow([f"{row[k]:.6g}" if isinstance(row[k], float) else row[k]
                                      for k in CURVE_FIELDS])
            fh.write(buf.getvalue())
        with (self.out / "log.jsonl").open("a") as fh:
            fh.write(json.dumps({"kind": "update", "version": self.version,
                                 "episodes": [e.ep for e in batch],
                                 "versions": [e.version for e in batch], **row}) + "\n")
        self.curve.append(row["elratio"])
        self.last_row = row
        log.info("learner: version %d, elratio %.3f", self.version, row["elratio"])
        self.status(force=True)
        return True

    def save(self) -> None:
        payload = self.policy.payload({"command": "swarm learner", "version": self.version,
                                       "episodes": self.c.episodes, "run_id": self.lc.run_id})
        payload["learner"] = {"version": self.version, "optimizer": self.opt.state_dict(),
                              "train": dataclasses.asdict(self.tc),
                              "counters": dataclasses.asdict(self.c)}
        save_checkpoint(self.ckpt, payload)

    def status(self, force: bool = False) -> dict[str, Any] | None:
        """Publish the status record when it is due (or `force`d); returns it, None if not due."""
        now = time.monotonic()
        if not force and now - self._last_status < self.lc.status_every:
            return None
        self._last_status = now
        rec = {"version": self.version, "episodes": self.c.episodes, "updates": self.c.updates,
               "pending": len(self.pending), "ready": len(self.ready),
               "stale_used": self.c.stale_used, "stale_dropped": self.c.stale_dropped,
               "incomplete": self.c.incomplete, "bad": self.c.bad,
               "worker_episodes": self.c.worker_episodes,
               "rollout_bytes": self.c.rollout_bytes,
               "rollout_bytes_per_s": self.c.rollout_bytes / max(now - self.t0, 1e-9),
               "curve": self.curve[-40:], "last": {k: self.last_row.get(k) for k in
                                                   ("elratio", "reward", "loss")},
               "wall": time.time()}
        self.status_pub.put(pack_record(K_LSTATUS, rec))
        return rec

    def run(self, seed: int, stop: Any = lambda: False) -> dict[str, Any]:
        ents = self._declare()
        try:
            self.weights_pub.put(self.weights_payload)  # late joiners also query it
            while not stop():
                try:
                    kind, key, payload = self.q.get(timeout=0.05)
                    self.handle(kind, key, payload)
                except queue.Empty:
                    pass
                self.join_ready(seed)
                self.maybe_update()
                self.status()
            return self.status(force=True)
        finally:
            for e in ents:
                e.undeclare()


def main(cfg: WorldConfig, lc: LearnerConfig, tc: TrainConfig, zopts: ZenohOptions,
         seed: int, stop: Any = lambda: False) -> dict[str, Any]:
    """Open a session and learn until interrupted (or `stop()`); returns the last status."""
    with zenoh.open(zopts.to_config()) as session:
        learner = Learner(cfg, lc, tc, session)
        try:
            return learner.run(seed, stop)
        except KeyboardInterrupt:
            return learner.status(force=True)
