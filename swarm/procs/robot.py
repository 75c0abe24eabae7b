"""A robot process: one robot, one Zenoh session, the same policy code as the batched evaluator.

Per tick: take the observation from the world, append the position to its own trajectory,
publish the trajectory message, take the radio's bundle of what it heard, (for a chained policy)
take the predecessor's hidden-state message, decide with `world.decentral.robot_view` and the
shared policy, publish its own hidden-state message (to the radio, or on a fast-lane tick to the
successors its bundle names) and the action. It keeps acting for as long as the world is alive
and exits by itself when the world's liveliness token disappears.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from typing import Any

import numpy as np
import zenoh

from policies.base import Policy
from swarm.common.policy_spec import build_inference
from swarm.net.inbox import LAST_PUT_S, Inbox, publisher, replies, tally
from swarm.net.keys import Keys
from swarm.net.learning import RobotRollout, RolloutTick, Weights
from swarm.net.messages import (
    K_RESULT,
    K_RSTATUS,
    Action,
    BadMessage,
    Bundle,
    Hidden,
    Obs,
    Traj,
    pack_record,
    unpack_record,
)
from swarm.net.zconfig import ZenohOptions, open_session
from swarm.procs.robot_direct import Heard, with_delivery
from swarm.procs.robot_status import (
    RobotCounters,
    TickGuard,
    WorldLeft,
    attention_of,
    count_after_end,
    hop_deadline,
    join_run,
)
from swarm.procs.runconfig import RunConfig
from world.config import ConfigError, WorldConfig
from world.core import check_actions
from world.decentral import TrajMessages, robot_view

log = logging.getLogger("swarm.robot")
ROLLOUT_STREAM = 7  # counter-based noise stream of the rollout-loss fault
STALL_S = 0.5  # a wait that overran its timeout by this much means the process was stopped
REJOIN_S = 10.0  # how long a robot that just stalled waits for the world's token to come back
VIRTUAL_HOP_FLOOR = 0.5  # virtual clock: no predecessor's slot ends before half the budget
GONE_S = 1.0  # how long any other robot waits before it takes a vanished token for the world's end


class RobotProcess:
    """Robot `robot` of a run."""

    attn: tuple[int, list[float]] | None = None  # the last decision's attention (t, weights)
    direct: Any = None  # swarm.procs.robot_direct.DirectDelivery with --delivery direct
    sent_hidden = (-1, -1)  # (episode, tick) of the last hidden-state message sent
    left = False  # it gave up on a world whose token stayed gone (no `end` record came)
    origin = -1  # the learner whose weights it acts with (Weights.origin; -1: a checkpoint's)

    def __init__(self, robot: int, cfg: WorldConfig, run: RunConfig, session: zenoh.Session,
                 policy: Policy) -> None:
        if not 0 <= robot < cfg.n_robots:
            raise ConfigError(f"robot id {robot} outside 0..{cfg.n_robots - 1}")
        self.robot, self.cfg, self.run_cfg, self.session = robot, cfg, run, session
        self.keys = Keys(run.run_id)
        self.policy = policy
        self.inbox: Inbox | None = None
        self.c = RobotCounters()
        self.world_alive = False
        self.world_seen = False
        self.ended = False  # the world announced the run's end
        self._last_stall = -1e9  # monotonic time the last stall ended
        self._watch = threading.Thread(target=self._stall_watch, daemon=True)
        self._watch.start()
        self.ep = -1
        self.ticks = TickGuard(cfg.horizon, run.first_episode, run.episodes)
        self.visited = np.zeros(cfg.cells, dtype=bool)
        self.recent: list[int] = []
        self._bundles: dict[tuple[int, int], Bundle] = {}
        self._hidden: dict[tuple[int, int, int], Hidden] = {}
        self.traj_pub = publisher(session, self.keys.traj(robot))
        self.act_pub = publisher(session, self.keys.action(robot))
        self.hid_pub = publisher(session, self.keys.hidden(robot), express=True)
        self._succ_pubs: dict[int, Any] = {}  # successor -> publisher on its hidden inbox
        self.status_pub = publisher(session, self.keys.robot_status(robot))
        # learning in the field (run.train): weights version in use, the next one, the record
        self.train = run.train and getattr(policy, "learned", False)
        self.version = 0
        self.next_weights: Any = None
        self.record: list[RolloutTick] = []
        self.roll_pub = publisher(session, self.keys.rollout(robot)) if self.train else None

    @property
    def last_stall(self) -> float:
        return self._last_stall

    def _stall_watch(self, period: float = 0.1) -> None:
        """A heartbeat thread: a gap between beats over STALL_S means the whole process was
        stopped (SIGSTOP) or starved; counted, and remembered so that a session that dropped
        meanwhile is taken for this robot's own absence, not the world's end."""
        last = time.monotonic()
        while True:
            time.sleep(period)
            now = time.monotonic()
            if now - last > period + STALL_S:
                self.c.stalls += 1
                self._last_stall = now
                log.warning("robot %d was stalled %.1f s", self.robot, now - last - period)
            last = now

    def _declare(self) -> Inbox:
        k, r = self.keys, self.robot
        inbox = Inbox(self.session) if self.direct is None else self.direct.inbox()
        if self.train:
            inbox.subscribe(k.weights, "weights")
        return (inbox.subscribe(k.obs(r), "obs").subscribe(k.inbox(r), "bundle")
                .subscribe(k.inbox_hidden(r), "hidden").subscribe(k.end, "end")
                .liveliness(k.alive_world, "world")
                .token(k.alive_robot(r)))

    def _bad(self, key: str, why: str) -> None:
        self.c.bad += 1
        if tally(self.c.bad_by_key, key):
            log.warning("robot %d dropped bad payload on %s: %s", self.robot, key, why)

    def _next(self, deadline: float) -> tuple[str, Any] | None:
        """The next valid message before `deadline` (bad ones dropped and counted)."""
        assert self.inbox is not None
        while True:
            ev = self.inbox.next(deadline - time.monotonic())
            if ev is None:
                return None
            kind, key, payload = ev
            if kind == "end":
                try:
                    rec = unpack_record(payload or b"", K_RESULT)
                    if rec.get("run_id") != self.run_cfg.run_id:
                        raise BadMessage("an end record of another run")
                except BadMessage as exc:
                    self._bad(key, str(exc))
                    continue
                self.ended = True
                return ("end", None)
            if kind in ("world:live", "world:dead"):
                self.world_alive = kind == "world:live"
                self.world_seen |= self.world_alive
                return ("wlive" if self.world_alive else "wdead", None)
            self.c.msgs_in += 1
            self.c.bytes_in += len(payload or b"")
            if kind == "weights":
                self.offer_weights(payload or b"", key)
                continue
            try:
                if kind == "obs":
                    msg: Any = self._check_obs(Obs.unpack(payload or b"", self.cfg))
                elif kind == "bundle":
                    b = Bundle.unpack(payload or b"", self.cfg)
                    if b.robot != self.robot:
                        raise BadMessage(f"addressed to robot {b.robot}")
                    self.ticks.tick(b.ep, b.t)  # (before its messages are unpacked)
                    msg = Heard.of(self.cfg, b)
                else:
                    msg = Hidden.unpack(payload or b"", self.cfg)
                if kind != "hidden" and msg.robot != self.robot:
                    raise BadMessage(f"addressed to robot {msg.robot}")
                if kind != "obs":
                    self.ticks.tick(msg.ep, msg.t)
            except BadMessage as exc:
                self._bad(key, str(exc))
                continue
            return (kind, msg)

    def _check_obs(self, obs: Obs) -> Obs:
        """`TickGuard.obs`, then what was kept for a tick now past is dropped as stale."""
        self.ticks.obs(obs.ep, obs.t, obs.y, obs.x)
        for store in (self._bundles, self._hidden):
            for key in [k for k in store if k[:2] < (obs.ep, obs.t)]:
                del store[key]  # type: ignore[attr-defined]
                self.c.stale += 1
        return obs

    def _wait(self, kind: str, ep: int, t: int, sender: int | None, deadline: float) -> Any:
        """Wait for a bundle/hidden of tick (ep, t), keeping early ones and dropping stale ones."""
        if self.direct is not None:  # assembled from the peers' messages, no radio
            return self.direct.wait(kind, ep, t, sender, deadline)
        store = self._bundles if kind == "bundle" else self._hidden
        want = (ep, t) if kind == "bundle" else (ep, t, sender)
        while True:
            got = store.pop(want, None)  # type: ignore[call-overload]
            if got is not None:
                return got
            item = self._next(deadline)
            if item is None:
                return None
            k, msg = item
            if k == "wdead":
                return None
            if k == "obs":
                self._pending_obs = msg
                return None
            if k in ("bundle", "hidden"):
                self._keep(k, msg, ep, t)

    def _keep(self, kind: str, msg: Any, ep: int, t: int) -> None:
        """A bundle or hidden state that is not the one awaited: kept for its tick if that is
        not past (ep, t) (`TickGuard.tick` bounds how far ahead), else counted stale."""
        if (msg.ep, msg.t) < (ep, t):
            self.c.stale += 1
            return
        if kind == "bundle":
            self._bundles[(msg.ep, msg.t)] = msg
        else:
            self._hidden[(msg.ep, msg.t, msg.robot)] = msg  # type: ignore[index]

    def offer_weights(self, payload: bytes, key: str) -> None:
        """Keep a newer weights version for the next episode boundary; reject bad ones."""
        from swarm.learn.weights import check_weights

        try:
            w = Weights.unpack(payload)
            check_weights(self.policy, w)  # type: ignore[arg-type]
        except (BadMessage, ValueError) as exc:  # (ValueError: numpy's, should a check miss)
            self.c.weights_bad += 1
            log.warning("robot %d rejected weights on %s: %s", self.robot, key, exc)
            self.status()  # visible at once on the dashboard
            return
        have = self.next_weights or self  # (the newest kept: for the next episode, or in use)
        if w.newer_than(have.version, have.origin):  # (another learner's: whatever version)
            self.next_weights = w

    def adopt_weights(self) -> None:
        """At an episode boundary: switch to the newest weights received, if they fit."""
        from swarm.learn.weights import adopt

        w, self.next_weights = self.next_weights, None
        if w is None:
            return
        try:
            adopt(self.policy, w)  # type: ignore[arg-type]
            self.version, self.origin = w.version, w.origin
        except BadMessage as exc:
            self.c.weights_bad += 1
            log.warning("robot %d rejected weights: %s", self.robot, exc)

    def catch_up(self, version: int, tries: int = 5) -> None:
        """Lockstep training (`train_sync`): the world named the version of this episode; one
        still on its way is fetched from the learner's queryable. Not got: counted, played on."""
        for _ in range(tries):
            self.fetch_weights()
            self.adopt_weights()
            if self.version >= version:
                return
        self.c.weights_late += 1
        log.warning("robot %d plays episode %d with weights version %d, not %d", self.robot,
                    self.ep, self.version, version)

    def fetch_weights(self, timeout: float = 1.0) -> None:
        """A late joiner asks the learner for the current weights (none: keep its own)."""
        for payload in replies(self.session, self.keys.weights, timeout):
            self.offer_weights(payload, self.keys.weights)

    def on_obs(self, obs: Obs) -> None:
        cfg, r = self.cfg, self.robot
        if self.direct is not None:
            self.direct.begin(obs)
        if obs.ep != self.ep or obs.t == 0:
            self.ep = obs.ep
            self.policy.reset(1)
            self.visited[:] = False
            self.recent = []
            self.record = []
            if self.train:
                self.adopt_weights()  # never mid-episode
                if obs.version is not None and self.version < obs.version:
                    self.catch_up(obs.version)
        cell = obs.y * cfg.width + obs.x
        self.visited[cell] = True
        self.recent = (self.recent + [cell])[-cfg.recent_len:]
        if obs.done:
            if self.train and self.record and self.roll_pub is not None:
                from world.noise import uniform

                lost = self.run_cfg.rollout_loss > 0 and float(uniform(
                    self.run_cfg.seed, obs.ep, 0, r, 1, stream=ROLLOUT_STREAM)[0]) < \
                    self.run_cfg.rollout_loss
                if lost:  # the injected rollout-traffic fault: the learner never hears it
                    self.c.rollouts_lost += 1
                else:
                    payload = RobotRollout(obs.ep, r, self.record).pack()
                    self.roll_pub.put(payload)
                    self.c.msgs_out += 1
                    self.c.bytes_out += len(payload)
            self.record = []
            return
        t_recv = time.monotonic()
        traj = Traj(obs.ep, obs.t, r, obs.y, obs.x, np.packbits(self.visited).tobytes(),
                    self.recent, obs.patch).pack()
        self.traj_pub.put(traj)
        self.c.msgs_out += 1
        self.c.bytes_out += len(traj)
        # Act before the world's deadline whatever is missing (a late message is never used).
        budget = 0.95 * obs.budget_ms / 1e3
        virtual = self.run_cfg.clock == "virtual"
        w0 = time.perf_counter()
        # virtual clock: the world holds the bundles up to its watchdog for a robot that hung
        # before sending, then gives the decisions a watchdog of their own
        bundle = self._wait("bundle", obs.ep, obs.t, None, t_recv + budget * (2 if virtual else 1))
        self.c.wait_ms += 1e3 * (time.perf_counter() - w0)
        if bundle is None:
            self.c.missed += 1
            return
        deadline = (time.monotonic() if virtual else t_recv) + budget
        self.c.last_latency_ms = 1e3 * (time.monotonic() - t_recv)
        heard = bundle.msgs
        t0, waited, errors = time.perf_counter(), self.c.wait_ms, self.c.errors
        try:
            # the predecessor slots count from the deadline's start (the bundle in virtual time)
            action, chain_ok = self.decide(obs, heard, deadline - budget, deadline, bundle.succ)
        except Exception as exc:  # a view no world would send (or a policy's bug) must not take
            self.c.errors += 1  # the robot down, nor hold the tick up: it stays in place
            log.error("robot %d could not decide at tick %d (it stays): %s: %s", r, obs.t,
                      type(exc).__name__, exc)
            action, chain_ok = 0, False
            if self.policy.chained and self.sent_hidden != (obs.ep, obs.t):
                with contextlib.suppress(Exception):  # (a session that fails: nothing to do)
                    self.send_hidden(Hidden(obs.ep, obs.t, r, 0, b""), bundle.succ)
        # planning time without the wait for the predecessor (reported apart, as wait_ms)
        ms = max(0.0, 1e3 * (time.perf_counter() - t0) - (self.c.wait_ms - waited))
        self.c.compute_ms += ms
        self.c.decisions += 1
        if self.train and self.c.errors == errors:  # (a tick it could not decide: not learnt)
            probs = self.policy.last_probs  # type: ignore[attr-defined]
            logp = float(np.log(max(float(probs[0, r, action]), 1e-30)))
            self.record.append(RolloutTick(traj, np.packbits(heard.present[0]).tobytes(),
                                           chain_ok, action, logp, float(obs.reward),
                                           self.version))
        direct = self.direct is not None  # then the world learns whom it heard from it
        a = Action(obs.ep, obs.t, r, int(action), ms,
                   self.direct.link.bucket() if direct else None,
                   np.packbits(heard.present[0]).tobytes() if direct else b"").pack()
        self.act_pub.put(a)
        self.c.msgs_out += 1
        self.c.bytes_out += len(a)
        # attention is drawn live: every tick when someone watches (a paced run), else with
        # the counters every 5 ticks (no extra message, nor its computation, in benchmarks)
        if obs.t % 5 == 0 or self.run_cfg.pace > 0:
            self.attn = attention_of(self.policy, r, cfg.n_robots, obs.t)
            if obs.t % 5 == 0 or self.attn is not None:
                self.status()

    def decide(self, obs: Obs, heard: TrajMessages, t_start: float, deadline: float,
               succ: list[int] | None = None) -> tuple[int, bool]:
        """The action (and whether the predecessor's hidden-state message was used) of this
        robot at `obs`'s tick from what it heard; chained policies wait for the predecessor.
        With `succ` (the radio's fast lane), the hidden-state message also goes straight to
        those successors."""
        cfg, r = self.cfg, self.robot
        view = robot_view(cfg, self.run_cfg.seed, obs.ep, obs.t, r, heard, obs.reward)
        chain_ok = True
        if self.policy.chained:
            prepared = self.policy.prepare_chain(  # type: ignore[attr-defined]
                view, self.run_cfg.greedy)  # before waiting: only decoding needs the predecessor
            pred = int(prepared.pred[0])
            hidden = None
            if pred >= 0:
                w0 = time.perf_counter()
                floor = VIRTUAL_HOP_FLOOR if self.run_cfg.clock == "virtual" else 0.0
                hidden = self._wait("hidden", obs.ep, obs.t, pred,
                                    hop_deadline(t_start, deadline, r, cfg.n_robots, floor))
                self.c.wait_ms += 1e3 * (time.perf_counter() - w0)
                if hidden is None or len(hidden.state) != 4 * self.policy.state_size or \
                        not self.policy.state_ok(hidden.vector(), obs.t):
                    # lost, late or malformed: decode as if there were no predecessor
                    self.c.missed_hidden += 1
                    view.chain_ok = np.zeros((1, cfg.n_robots), dtype=bool)
                    hidden = None
                    chain_ok = False
            actions, state = self.policy.act_with_chain(  # type: ignore[attr-defined]
                view, None if hidden is None else hidden.vector()[None],
                None if hidden is None else np.array([hidden.action]),
                greedy=self.run_cfg.greedy, prepared=prepared)
            action = int(check_actions(actions, view.receivers.shape)[0, r])  # (as eval's)
            self.send_hidden(Hidden(obs.ep, obs.t, r, action,
                                    np.asarray(state[0], "<f4").tobytes()), succ)
        else:
            actions = self.policy.act(view, greedy=self.run_cfg.greedy)
            action = int(check_actions(actions, view.receivers.shape)[0, r])
        return action, chain_ok

    def send_hidden(self, h: Hidden, succ: list[int] | None) -> None:
        """This tick's hidden-state message to the radio, or on a fast-lane tick (`succ`) to
        each successor first (each one's decode waits for it). An empty state says that none
        will come this tick: the successors decode without it at once."""
        payload, self.sent_hidden = h.pack(), (h.ep, h.t)  # (sent once, even if a put fails)
        for i in succ or ():
            pub = self._succ_pubs.get(i)
            if pub is None:
                pub = self._succ_pubs[i] = publisher(self.session, self.keys.inbox_hidden(i),
                                                     express=True)
            pub.put(payload)
        if succ is None:
            self.hid_pub.put(payload)
        n_out = len(succ) if succ is not None else 1
        self.c.msgs_out += n_out
        self.c.bytes_out += len(payload) * n_out

    def status(self, final: bool = False) -> None:
        rec = self.c.record(self.robot, self.ep, final, self.version,
                            self.inbox.dropped if self.inbox is not None else {})
        if self.attn is not None:
            rec["attn_t"], rec["attn"] = self.attn
        self.status_pub.put(pack_record(K_RSTATUS, rec))

    def run(self, wait_world: float = 30.0, rejoin: float = REJOIN_S) -> RobotCounters:
        """Act until the world ends the run (its `end` record), or its liveliness token has been
        gone for `rejoin` seconds: a token that vanishes because this robot's own session dropped
        (the process hung past the lease) comes back when the session reconnects, and the robot
        rejoins the run (`rejoins` counts it)."""
        self.inbox = self._declare()
        try:
            if self.train:
                self.fetch_weights()
            deadline = time.monotonic() + wait_world
            gone_since: float | None = None
            grace = rejoin
            while not self.ended:
                self._pending_obs: Obs | None = None
                if not self.world_seen:
                    wait_until = deadline
                elif gone_since is not None:
                    wait_until = gone_since + grace
                else:
                    wait_until = time.monotonic() + 3600
                item = self._next(wait_until)
                if item is None:
                    if not self.world_seen:
                        raise TimeoutError(f"no world within {wait_world:g} s")
                    if gone_since is not None and time.monotonic() >= gone_since + grace:
                        log.warning("robot %d: the world left before the run's end (its token "
                                    "gone %.0f s); exiting", self.robot, grace)
                        self.left = True
                        break
                    continue
                kind, msg = item
                if kind in ("bundle", "hidden"):  # between decisions: early, or too late
                    last = self.ticks.last or (-1, -1)
                    self._keep(kind, msg, last[0], last[1] + 1)
                while kind == "obs" and msg is not None:
                    self.on_obs(msg)  # (may itself see the world's token go or come back)
                    msg, self._pending_obs = self._pending_obs, None
                if not self.world_alive and self.world_seen and gone_since is None:
                    gone_since = time.monotonic()
                    # its own stall (hung past the lease) explains a dropped session; otherwise
                    # the world is gone, unless its token is back within a short grace
                    stalled = time.monotonic() - self.last_stall < rejoin
                    grace = rejoin if stalled else min(GONE_S, rejoin)
                elif self.world_alive and gone_since is not None:
                    gone_since = None
                    self.c.rejoins += 1
                    log.warning("robot %d: world back, rejoining", self.robot)
            if self.ended:  # (what the world sent just before its end comes after it too)
                count_after_end(self.inbox, self.c)
            self.status(final=True)  # the counters a run's result reports of this robot
            time.sleep(LAST_PUT_S)
            return self.c
        finally:
            self.inbox.close()


def main(robot: int, run_id: str, zopts: ZenohOptions, wait_world: float = 30.0,
         settle: float = 0.0) -> RobotCounters:
    """Join run `run_id` as robot `robot`: act until the run ends (WorldLeft: its world left)."""
    keys = Keys(run_id)
    with open_session(zopts, wait_world) as session:
        rec = join_run(session, keys, robot, wait_world, settle)
        cfg, run = rec.world, rec.run
        # learned policies act in numpy (policies.infer): no robot process imports torch
        policy = build_inference(run.policy, cfg, run.checkpoint)
        policy.reset(1)
        proc = RobotProcess(robot, cfg, run, session, policy)
        counters = with_delivery(proc, rec.faults).run(wait_world)  # swarm.procs.robot_direct
        if proc.left:
            raise WorldLeft(f"robot {robot}: the world of run {run_id} left before the run's "
                            f"end (episode {proc.ep}, {counters.decisions} decisions made)")
        return counters
