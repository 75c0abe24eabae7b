"""The world process: owns the grid and the clock, hosts the radio, steps once per tick.

Per tick t: send every live robot its observation; hand each robot its bundle of trajectory
messages through the radio once every live robot has sent; forward hidden-state messages to the
successors (on a tick with no link fault the robots send them themselves: the fast lane);
collect actions until every live robot has acted; step with `world.core.step`. The real clock's
tick deadline also ends the waits (the bundles at half of it; a robot that missed it stays in
place: a timeout); virtual time waits for every live robot, up to the wall-clock watchdog. All
input goes through one queue and is checked there: a bad payload is dropped and counted with its
key, never raised.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import deque
from typing import Any

import msgpack
import numpy as np
import zenoh

from policies import is_chained
from swarm.learn.evaluate import EvalResult
from swarm.net.direct import DirectTally
from swarm.net.faults import plan_from_table
from swarm.net.faults.control import MAX_PENDING, FaultSchedule, check_control
from swarm.net.inbox import LAST_PUT_S, Event, Inbox, Outbox, check_free, publisher, tally
from swarm.net.keys import Keys
from swarm.net.learning import EpisodeRecord, LearnerGate
from swarm.net.messages import (
    K_CONTROL,
    K_LSTATUS,
    K_RESULT,
    K_RSTATUS,
    K_STATUS,
    Action,
    BadMessage,
    Hidden,
    Obs,
    Traj,
    pack_record,
    unpack_record,
)
from swarm.net.presence import Presence
from swarm.net.radio import Radio, TickInbox, chain_times, has_all
from swarm.net.zconfig import ZenohOptions, open_session
from swarm.procs.runconfig import RunConfig, RunRecord, leave_grace
from world import core
from world.config import ConfigError, WorldConfig

log = logging.getLogger("swarm.world")
PHASES = ("obs", "collect", "radio", "decide", "step")  # see WorldProcess.phase_ms
SCHEMA = {"traj": Traj, "hidden": Hidden, "action": Action}  # subscription kind -> schema


class WorldProcess:
    """One world of one run; `run()` plays every episode and returns the result record."""

    def __init__(self, cfg: WorldConfig, run: RunConfig, session: zenoh.Session,
                 faults: dict[str, Any] | None = None, fast_lane: bool = True,
                 supervised: bool = False) -> None:
        self.cfg, self.run_cfg, self.session = cfg, run, session
        self.keys = Keys(run.run_id)
        self.inbox: Inbox | None = None
        # the human-unit [faults] table in force, and the live changes waiting for their tick
        self.faults = FaultSchedule(dict(faults or {}), run.seed, cfg.n_robots)
        self.served = RunRecord(cfg, run, self.faults.table, supervised=supervised)
        self._record = self.served.pack()  # to the robots, and to `swarm fault`
        self.radio = Radio(cfg, plan_from_table(self.faults.table, run.seed))
        self.virtual = run.clock == "virtual"
        # virtual clock + chain: a tick also waits for every hidden-state message, so each one
        # is charged to its sender's bucket in order (swarm.net.channel), as in the evaluator
        self.chained = self.virtual and is_chained(run.policy) and run.delivery == "radio"
        # the radio's fast lane: on a tick with no link fault the bundles name each robot's
        # successors and the robots send them the message themselves (see the docstring)
        self.fast_lane = self.chained and fast_lane
        # direct delivery (swarm.net.direct): robots deliver to one another and report counts
        self.direct = DirectTally(cfg.n_robots) if run.delivery == "direct" else None
        if self.virtual:
            self.radio.use_virtual_clock(run.tick_timeout)
        self._outbox = Outbox(self._put)  # the real clock's radio deliveries, at their times
        self.run_tick = 0
        self.planning_ms = 0.0  # robots' reported planning time, summed
        # where a tick's wall time goes, summed over ticks (ms): publishing observations,
        # collecting trajectories, the radio (bundles and hidden-state forwarding), waiting for
        # the decisions (the chain of hidden-state messages included), stepping and status
        self.phase_ms = dict.fromkeys(PHASES, 0.0)
        self.chain_ms: list[list[float]] = []  # per chain depth: [sum of ms, messages]
        # liveliness tokens, less the robots a process fault of the plan holds down (virtual
        # clock: at exactly their tick; swarm.net.presence); `alive` and `live` are its views
        self.presence = Presence(cfg.n_robots, self.radio.plan.process, gated=self.virtual,
                                 restart_crashed=run.restart_crashed)
        self.alive, self.live = self.presence.alive, self.presence.live
        # the live robots sent this tick's observation, less any that died since (one that comes
        # alive mid-tick joins at the next: nobody waits for its action)
        self.tick_live: set[int] = set()
        self.ever_alive = self.presence.ever_alive
        self.learner_alive = not run.train  # a training run's first tick waits for its learner
        self.gate = LearnerGate(run.first_episode) if run.train_sync else None  # lockstep
        self.bad: dict[str, int] = {}
        self.timeouts = 0
        self.fast_lane_ticks = 0  # ticks whose hidden-state messages went robot to robot
        self.late = 0
        self._held: deque[Event] = deque()  # events read between ticks, for the tick's loop
        self.stop, self.stopped = False, ""
        self._pubs: dict[str, zenoh.Publisher] = {}

    # --- network plumbing -------------------------------------------------------------------
    def _put(self, key: str, payload: bytes) -> None:
        pub = self._pubs.get(key)
        if pub is None:
            # hidden-state forwards go out at once: each hop of the chain waits for one
            pub = self._pubs[key] = publisher(self.session, key,
                                              express=key.startswith(self.keys.inbox_hidden(0)[:-1]))
        pub.put(payload)

    def _count_bad(self, key: str, why: str) -> None:
        if tally(self.bad, key):
            log.warning("dropped bad payload on %s: %s", key, why)

    def _declare(self) -> Inbox:
        k = self.keys
        inbox = Inbox(self.session)
        if self.direct is not None:  # the robots' counters of direct delivery
            inbox.subscribe(k.robot_status("*"), "rstatus")
        if self.run_cfg.train:  # its token follows its subscriptions (swarm.procs.learning.learner)
            inbox.liveliness(k.alive_learner, "learner")
        if self.gate is not None:
            inbox.subscribe(k.learner_status, "lstatus")
        return (inbox.subscribe(k.traj("*"), "traj")
                .subscribe(k.hidden("*"), "hidden").subscribe(k.action("*"), "action")
                .subscribe(k.control, "control").queryable(k.config, lambda: self._record)
                .liveliness(k.alive_robot("*"), "robot").token(k.alive_world))

    def _liveness(self, live: bool, key: str) -> None:
        try:
            robot = Keys.robot_of(key)
        except ValueError:
            return
        if 0 <= robot < self.cfg.n_robots:
            self.presence.token(robot, live)
            if not live:
                self.tick_live.discard(robot)
            log.info("robot %d %s", robot, "alive" if live else "gone")

    # --- the tick loop ----------------------------------------------------------------------
    def wait_for_robots(self) -> None:
        """Until every robot (or start_timeout: those alive then) and a training run's learner
        is alive: the learner starts beside the robots; no episode may end before it listens."""
        deadline = time.monotonic() + self.run_cfg.start_timeout
        while not (self.alive.all() and self.learner_alive) and time.monotonic() < deadline \
                and not self.stop:
            self._pump(deadline)
        if not self.alive.any():
            raise RuntimeError(f"no robot came alive within {self.run_cfg.start_timeout:g} s")
        if not self.alive.all():  # (in the result's never_joined unless they come later)
            log.warning("robots %s not alive within %g s: the run goes on without them",
                        np.flatnonzero(~self.alive).tolist(), self.run_cfg.start_timeout)
        if not self.learner_alive and not self.stop:
            raise RuntimeError(f"no learner came alive within {self.run_cfg.start_timeout:g} s")

    def _pump(self, deadline: float, tick: TickInbox | None = None) -> bool:
        """Handle one queued event (or due delivery) before `deadline`; False when it passed."""
        assert self.inbox is not None
        self._outbox.flush()
        if self._held:
            return self._handle(self._held.popleft(), tick)
        wait_until = self._outbox.until(deadline)
        ev = self.inbox.next(wait_until - time.monotonic())
        if ev is None:
            self._outbox.flush()
            return time.monotonic() < deadline
        return self._handle(ev, tick)

    def _idle(self, until: float) -> None:
        """Between ticks, until `until`: a control is acted on as it comes, so a fault change
        that arrived before a tick starts applies from that tick; any other event waits for the
        tick's own loop, as before (liveness, say, must not change the tick's observations)."""
        assert self.inbox is not None
        for _ in range(10_000):  # (a flood cannot hold the tick back for ever)
            ev = self.inbox.next(until - time.monotonic())
            if ev is None:
                return
            if ev.kind == "control":
                self._handle(ev, None)
            else:
                self._held.append(ev)

    def _handle(self, ev: Event, tick: TickInbox | None) -> bool:
        """Act on one event (`tick`: the tick in play, None between ticks); True."""
        kind, key, payload = ev
        if kind in ("robot:live", "robot:dead"):
            self._liveness(kind == "robot:live", key)
            return True
        if kind in ("learner:live", "learner:dead"):
            self.learner_alive = kind == "learner:live"
            return True
        if kind == "control":
            try:  # the whole record checked before any field is acted on
                ctl = check_control(unpack_record(payload or b"", K_CONTROL), self.run_cfg.seed,
                                    self.cfg.n_robots)
            except (BadMessage, ConfigError) as exc:
                self._count_bad(key, str(exc))
                return True
            if ctl.stop and not self.stop:
                self.stop, self.stopped = True, ctl.why
            # (as the supervisor decides: a change its full queue drops is never signalled)
            self.presence.add(ctl.process, self.run_tick, limit=MAX_PENDING)
            if ctl.table is not None and not self.faults.add(ctl, self.run_tick) and \
                    (n := self.faults.counts["dropped"]) & (n - 1) == 0:  # (in fault_changes)
                log.warning("dropped a fault change (%d so far): %d wait already", n, MAX_PENDING)
            return True
        if kind in ("rstatus", "lstatus"):  # direct delivery's counters; the learner's progress
            try:
                if kind == "lstatus":
                    self.gate.offer(unpack_record(payload or b"", K_LSTATUS))  # type: ignore
                elif self.direct is not None:
                    self.direct.offer(unpack_record(payload or b"", K_RSTATUS))
            except BadMessage as exc:
                self._count_bad(key, str(exc))
            return True
        try:
            msg: Any = SCHEMA[kind].unpack(payload or b"", self.cfg)
            if Keys.robot_of(key) != msg.robot:
                raise BadMessage(f"robot id {msg.robot} does not match key")
        except (BadMessage, KeyError, ValueError) as exc:
            self._count_bad(key, str(exc))
            return True
        if tick is None or (msg.ep, msg.t) != (tick.ep, tick.t) or self.presence.held(msg.robot):
            self.late += 1  # (between ticks: a past one; or of a robot a process fault holds)
            return True
        seen = tick.traj if kind == "traj" else tick.sent_hidden if kind == "hidden" else \
            tick.action
        if msg.robot in seen:
            self._count_bad(key, f"a second {kind} message of robot {msg.robot} at tick {msg.t}")
            return True  # (a second process with its id, or a replay)
        if kind == "traj" and tick.delivered:  # after the bundles left: never used
            self.late += 1
        elif kind == "traj":
            self.radio.counters.traj_in += 1
            self.radio.counters.bytes_in += len(payload or b"")
            tick.traj[msg.robot] = (payload or b"", time.monotonic())
        elif kind == "hidden" and tick.fast_lane:  # robots send these to successors this tick
            self._count_bad(key, "hidden-state message to the radio on a fast-lane tick")
        elif kind == "hidden":
            self.radio.counters.hidden_in += 1
            tick.sent_hidden.add(msg.robot)
            tick.hidden_at.setdefault(msg.robot, time.perf_counter())
            if tick.delivered:
                self._forward_hidden(msg, payload or b"", tick)
            else:
                tick.hidden[msg.robot] = (msg, payload or b"")
        else:
            if tick.fast_lane:  # its hidden-state message went to its successors before it
                self.radio.counters.hidden_in += 1
                self.radio.counters.hidden_delivered += len(self.radio.successors(msg.robot))
                tick.hidden_at.setdefault(msg.robot, time.perf_counter())
            tick.action[msg.robot] = msg
            if self.direct is not None:  # its bucket, and whom it heard (the dashboard's links)
                self.direct.took(msg, self.radio.delivered)
        return True

    def _forward_hidden(self, msg: Hidden, payload: bytes, tick: TickInbox) -> None:
        t0 = time.perf_counter()
        for when, i, p in self.radio.hidden_sends(msg, payload, time.monotonic(),
                                                  tick.hidden_deadline):
            self._outbox.schedule(when, self.keys.inbox_hidden(i), p)
        self.phase_ms["radio"] += 1e3 * (time.perf_counter() - t0)

    def _deliver(self, state: core.WorldState, tick: TickInbox) -> None:
        t0 = time.perf_counter()
        yx = core.Layout.of(self.cfg).to_yx(state.pos[0])
        for when, i, bundle in self.radio.bundle_sends(tick, yx):
            self._outbox.schedule(when, self.keys.inbox(i), bundle)
        tick.delivered = True
        self.phase_ms["radio"] += 1e3 * (time.perf_counter() - t0)
        for msg, payload in tick.hidden.values():  # (timed on their own)
            self._forward_hidden(msg, payload, tick)

    def play_episode(self, ep: int, version: int | None = None
                     ) -> tuple[core.WorldState, list[np.ndarray], int]:
        """Play episode `ep` (`version`: the learner's, named at tick 0 in lockstep training)."""
        cfg, keys = self.cfg, self.keys
        state = core.reset(cfg, self.run_cfg.seed, [ep])
        lay = core.Layout.of(cfg)
        actions_log: list[np.ndarray] = []
        rewards: list[np.ndarray] = []  # per tick, for the learner (run.train)
        acted: list[np.ndarray] = []
        ticks = 0
        next_tick = time.monotonic()
        self.radio.new_episode()
        while True:
            self._idle(next_tick if self.run_cfg.pace > 0 else 0.0)
            if self.run_cfg.pace > 0:
                next_tick = max(next_tick, time.monotonic() - 1.0) + 1.0 / self.run_cfg.pace
            obs_faults = b""
            if not state.done:  # (a last observation's run tick is the next episode's first)
                self.presence.wait_up(self.presence.due(self.run_tick), self._pump,
                                      time.monotonic() + self.run_cfg.start_timeout)
            plan = self.faults.due(self.run_tick)  # each live change at its own tick
            if plan is not None:
                self.radio.set_plan(plan)
                log.info("faults now: %s", "; ".join(plan.describe()) or "none")
                self._record = dataclasses.replace(self.served, faults=self.faults.table).pack()
                if self.direct is not None:  # the robots hold the plan: this tick's obs carry it
                    obs_faults = msgpack.packb(self.faults.table)
            self._outbox.clear()  # nothing of an older tick is ever delivered
            state.alive[0] = self.alive
            t, done, yx = state.t, state.done, lay.to_yx(state.pos[0])
            patch = core.patches(cfg, state)[0]
            start = time.monotonic()
            # virtual: lateness is decided in virtual time (up to the watchdog); real: the wall
            timeout = self.run_cfg.watchdog if self.virtual else self.run_cfg.tick_timeout
            deadline = start + timeout
            budget_ms = 1e3 * timeout
            t_obs = time.perf_counter()
            live = b""
            if self.direct is not None:  # the tick's links come with its actions (Action.heard)
                live = np.packbits(self.alive).tobytes()
                self.radio.delivered = np.zeros((cfg.n_robots, cfg.n_robots), dtype=bool)
            self.tick_live = set(self.live)
            for i in np.flatnonzero(self.alive):
                held = self.direct.bucket_of(int(i), ep) if self.direct is not None else None
                self._put(keys.obs(int(i)), Obs(ep, t, int(i), int(yx[i, 0]), int(yx[i, 1]),
                                                 patch[i].tobytes(), float(state.last_reward[0, i]),
                                                 bool(done), budget_ms, live, obs_faults,
                                                 held, version if t == 0 else None).pack())
            if done and self.run_cfg.train and rewards:
                m = core.metrics(cfg, state)
                rec = EpisodeRecord(ep, np.stack(rewards).astype(np.float32), np.stack(acted),
                                    m.row(0))
                self._put(keys.episode, rec.pack())
            if done or self.stop:
                return state, actions_log, ticks
            # the radio stops waiting for senders (real clock: half way; virtual: never early)
            traj_deadline = deadline if self.virtual else start + timeout / 2
            # the plan is fixed for the tick by now: a fast-lane tick is one from its start, so a
            # hidden-state message sent to the radio is refused even before the bundles go out
            tick = TickInbox(ep, t, traj_deadline=start + 0.8 * timeout,
                             hidden_deadline=start + 0.9 * timeout,
                             fast_lane=self.fast_lane and self.radio.plan.zero)
            tick.delivered = self.direct is not None  # direct delivery: the robots' own
            radio0 = self.phase_ms["radio"]
            t_sent = t_delivered = time.perf_counter()
            self.phase_ms["obs"] += 1e3 * (t_sent - t_obs)
            live = self.tick_live  # (changes only with a liveness event, in _liveness)
            while True:
                if not tick.delivered and (has_all(tick.traj, live)
                                           or time.monotonic() >= traj_deadline):
                    t_delivered = time.perf_counter()
                    if self.virtual:  # the watchdog again for the decisions (a robot that
                        # hung, or died, before its trajectory held the bundles; it cannot act)
                        if not has_all(tick.traj, live):
                            live = {i for i in live if i in tick.traj}
                        deadline = time.monotonic() + timeout
                    self._deliver(state, tick)
                if tick.delivered and has_all(tick.action, live) and (
                        not self.chained or tick.fast_lane or has_all(tick.sent_hidden, live)):
                    break
                if self.stop or not self.alive.any():
                    break
                limit = deadline if tick.delivered else min(deadline, traj_deadline)
                if not self._pump(limit, tick) and time.monotonic() >= deadline \
                        and tick.delivered:
                    break
            t_acted = time.perf_counter()
            radio = self.phase_ms["radio"] - radio0  # this tick's bundles and forwarding
            self.phase_ms["collect"] += 1e3 * (t_delivered - t_sent)
            self.phase_ms["decide"] += max(0.0, 1e3 * (t_acted - t_delivered) - radio)
            chain_times(self.chain_ms, self.radio.pred, tick.hidden_at, t_delivered)
            acts = np.zeros((1, cfg.n_robots), dtype=np.int64)
            for i, msg in tick.action.items():
                acts[0, i] = msg.action
            self.planning_ms += sum(m.planning_ms for m in tick.action.values())
            missing = [i for i in sorted(self.tick_live) if i not in tick.action]
            self.timeouts += len(missing)
            self.fast_lane_ticks += tick.fast_lane
            state.alive[0] = self.alive
            reward = core.step(cfg, state, acts)
            if self.run_cfg.train:
                rewards.append(np.asarray(reward)[0].copy())
                did = np.zeros(cfg.n_robots, dtype=bool)
                did[list(tick.action)] = True
                acted.append(did & self.alive)
            actions_log.append(acts[0].copy())
            ticks += 1
            self.run_tick += 1
            self._status(state, ep, missing)
            self.phase_ms["step"] += 1e3 * (time.perf_counter() - t_acted)

    def _status(self, state: core.WorldState, ep: int, missing: list[int]) -> None:
        lay = core.Layout.of(self.cfg)
        rec = {
            "ep": ep, "t": state.t, "pos": lay.to_yx(state.pos[0]).tolist(),
            "alive": self.alive.tolist(), "elratio": float(state.elratio[0, state.t]),
            "block_coll": int(state.block_coll.sum()), "robot_coll": int(state.robot_coll.sum()),
            "dyn": lay.to_yx(state.dyn_cells[0][state.dyn_active[0]]).tolist(),
            "timeouts": missing, "bad": sum(self.bad.values()), "late": self.late,
            "run_tick": self.run_tick, "wall": time.time(),
            "radio": (self.direct or self.radio.counters).totals(),
            "clock": self.run_cfg.clock, "vtime": self.run_tick * self.run_cfg.tick_timeout,
            "faults": self.radio.plan.panel(), "heard_links": self.radio.heard_links(),
            "links": (self.direct or self.radio.counters).faulted_links(),
        }
        if state.t == 1:
            rec["static"] = np.argwhere(lay.inner(state.grid[0]) == core.STATIC).tolist()
        self._put(self.keys.status, pack_record(K_STATUS, rec))

    def run(self) -> dict[str, Any]:
        self.inbox = self._declare()
        try:
            self.wait_for_robots()
            parts, curves, actions = [], [], []
            ticks, t0 = 0, time.monotonic()
            rc = self.run_cfg
            for ep in range(rc.first_episode, rc.first_episode + rc.episodes):
                version = None if self.gate is None else self.gate.wait(
                    ep, self._pump, rc.start_timeout, lambda: self.stop)
                state, acts, n = self.play_episode(ep, version)
                ticks += n
                if self.stop:
                    break
                parts.append(core.metrics(self.cfg, state))
                curves.append(state.elratio)
                actions.append(np.array(acts, dtype=np.int8))  # [T, N], 1 byte an action
            wall = time.monotonic() - t0
            deadline = time.monotonic() + 5.0  # direct: each robot's counts after the last end
            while self.direct is not None and not self.stop and \
                    not self.direct.complete(self.alive, ep) and self._pump(deadline):
                pass
            result = self._result(parts, curves, actions, ticks, wall)
            self._put(self.keys.result, pack_record(K_RESULT, result))
            if rc.train:  # robots' and learner's traffic is routed through this session:
                # stay up until the supervisor has let the learner take the last episodes
                # (robots too: one that left at once could lose its last episode's record)
                deadline = time.monotonic() + 15.0
                while not self.stop and self._pump(deadline):
                    pass
            self._put(self.keys.end, pack_record(K_RESULT, {"run_id": rc.run_id}))
            deadline = time.monotonic() + leave_grace(self.cfg.n_robots)  # robots' final
            while self.presence.tokens and self._pump(deadline):  # statuses route through it
                pass
            time.sleep(LAST_PUT_S)  # the result and the end leave before the session closes
            return result
        finally:
            self.inbox.close()

    def _result(self, parts: list[core.EpisodeMetrics], curves: list[np.ndarray],
                actions: list[Any], ticks: int, wall: float) -> dict[str, Any]:
        rc = self.run_cfg
        out: dict[str, Any] = {"policy": rc.policy, "run_id": rc.run_id, "completed": len(parts)}
        if self.stop:  # only a control record stops a world before its last episode
            out["stopped"] = self.stopped  # (an operator's "control", or an "interrupt")
        out.update(EvalResult.none(rc.policy, rc.seed, self.cfg).summary(self.cfg))
        if parts:
            res = EvalResult.of(rc.policy, rc.seed,
                                np.arange(rc.first_episode, rc.first_episode + len(parts)),
                                parts, curves, wall_s=wall)
            out.update(res.summary(self.cfg))
            # per team decision: the robots' planning times of a tick, summed (CPU, not latency)
            out["planning_ms_per_decision"] = self.planning_ms / max(self.run_tick, 1)
            out["tick_ms"] = {k: v / max(self.run_tick, 1) for k, v in self.phase_ms.items()}
            if self.chain_ms:  # mean ms from the bundles going out to each depth's message
                out["chain_ms_by_depth"] = [s / max(n, 1) for s, n in self.chain_ms]
        c = self.radio.counters
        messages = c.totals() if self.direct is None else self.direct.totals()
        # whole messages that reached the world after their tick (`late` counts copies)
        messages["stale"] = self.late
        out.update({
            "ticks": ticks, "ticks_per_s": ticks / wall if wall > 0 else 0.0,
            "clock": rc.clock, "virtual_s": ticks * rc.tick_timeout if rc.clock == "virtual"
            else None, "delivery": rc.delivery,
            "messages": {**messages, "bad": sum(self.bad.values()), "bad_by_key": dict(self.bad),
                         **(self.inbox.dropped if self.inbox is not None else {})},
            "faults": self.faults.first, "faults_end": self.radio.plan.to_record(),
            "fault_changes": self.faults.summary(), "timeouts": self.timeouts,
            "fast_lane_ticks": self.fast_lane_ticks,
            "robots_lost": int((self.ever_alive & ~self.alive).sum()),
            "never_joined": np.flatnonzero(~self.ever_alive).tolist(),
            "actions": [a.tolist() for a in actions],
        })
        if self.gate is not None:
            out["train_sync"] = self.gate.summary()
        return out


def main(cfg: WorldConfig, run: RunConfig, zopts: ZenohOptions,
         faults: dict[str, Any] | None = None, supervised: bool = False) -> dict[str, Any]:
    """Open a session, play the run, return its result record (`supervised`: `swarm run` started
    it, from a spec). A config file's session (`--secure`) routes hidden states through here: its
    ACL may let only the world publish."""
    with open_session(zopts) as session:
        check_free(session, Keys(run.run_id).alive_world, f"a world of run {run.run_id}", 1.0)
        world = WorldProcess(cfg, run, session, faults, fast_lane=not zopts.may_acl,
                             supervised=supervised)
        return world.run()
