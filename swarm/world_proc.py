"""The world process: owns the grid and the clock, hosts the radio, steps once per tick.

Per tick t: send every live robot its observation; collect trajectory messages and hand each
robot its bundle through the radio as soon as every live robot has sent (or half the tick
deadline passed); forward hidden-state messages to the successors that need them; collect
actions until every live robot has acted or the deadline passed (a robot that missed it stays in
place, counted as a timeout); step with the same `world.core.step` as the batched evaluator.
Everything arriving from the network goes through one queue and is validated there: a bad
payload is dropped and counted with its key, never raised.
"""

from __future__ import annotations

import heapq
import logging
import os
import queue
import time
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import msgpack
import numpy as np
import zenoh

from swarm.evaluate import EvalResult
from swarm.faults import FaultPlan, plan_from_table
from swarm.keys import Keys
from swarm.messages import (
    K_CONTROL,
    K_RESULT,
    K_STATUS,
    Action,
    BadMessage,
    METRIC_NAMES,
    Bundle,
    EpisodeRecord,
    Hidden,
    Obs,
    Traj,
    pack_record,
    unpack_record,
)
from swarm.radio import Radio
from swarm.runconfig import RunConfig
from swarm.zconfig import ZenohOptions
from world import core
from world.config import ConfigError, WorldConfig, to_dict

log = logging.getLogger("swarm.world")


class WorldProcess:
    """One world of one run; `run()` plays every episode and returns the result record."""

    def __init__(self, cfg: WorldConfig, run: RunConfig, session: zenoh.Session,
                 on_status: Callable[[dict[str, Any]], None] | None = None,
                 faults: dict[str, Any] | None = None) -> None:
        self.cfg, self.run_cfg, self.session = cfg, run, session
        self.keys = Keys(run.run_id)
        self.q: queue.Queue[tuple[str, str, bytes | None]] = queue.Queue()
        self.fault_table = dict(faults or {})  # human-unit [faults] table; live changes merge in
        self.radio = Radio(cfg, plan_from_table(self.fault_table, run.seed))
        self._pending_plan: FaultPlan | None = None
        self._due: list[tuple[float, int, str, bytes]] = []  # scheduled radio deliveries
        self._seq = 0
        self.run_tick = 0
        self.planning_ms = 0.0  # robots' reported planning time, summed
        self.parent = None  # set by the supervisor's child: stop if the supervisor vanishes
        self.alive = np.zeros(cfg.n_robots, dtype=bool)
        self.ever_alive = np.zeros(cfg.n_robots, dtype=bool)
        self.bad: dict[str, int] = {}
        self.timeouts = 0
        self.late = 0
        self.stop = False
        self.on_status = on_status
        self._pubs: dict[str, zenoh.Publisher] = {}

    # --- network plumbing -------------------------------------------------------------------
    def _put(self, key: str, payload: bytes) -> None:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.session.declare_publisher(key)
        pub.put(payload)

    def _count_bad(self, key: str, why: str) -> None:
        self.bad[key] = self.bad.get(key, 0) + 1
        log.warning("dropped bad payload on %s: %s", key, why)

    def _serve_config(self, query: zenoh.Query) -> None:
        record = {"world": to_dict(self.cfg), "run": asdict(self.run_cfg)}
        query.reply(self.keys.config, msgpack.packb(record, use_bin_type=True))

    def _declare(self) -> list[Any]:
        k, q = self.keys, self.q
        sub = lambda key, kind: self.session.declare_subscriber(  # noqa: E731
            key, lambda s: q.put((kind, str(s.key_expr), s.payload.to_bytes())))
        ents = [
            sub(k.traj("*"), "traj"), sub(k.hidden("*"), "hidden"), sub(k.action("*"), "action"),
            sub(k.control, "control"),
            self.session.declare_queryable(k.config, self._serve_config),
            self.session.liveliness().declare_subscriber(
                k.alive_robot("*"), lambda s: q.put(
                    ("live" if s.kind == zenoh.SampleKind.PUT else "dead", str(s.key_expr), None)),
                history=True),
            self.session.liveliness().declare_token(k.alive_world),
        ]
        return ents

    def _liveness(self, kind: str, key: str) -> None:
        try:
            robot = Keys.robot_of(key)
        except ValueError:
            return
        if 0 <= robot < self.cfg.n_robots:
            self.alive[robot] = kind == "live"
            self.ever_alive[robot] |= kind == "live"
            log.info("robot %d %s", robot, "alive" if kind == "live" else "gone")

    # --- the tick loop ----------------------------------------------------------------------
    def wait_for_robots(self) -> None:
        deadline = time.monotonic() + self.run_cfg.start_timeout
        while not self.alive.all() and time.monotonic() < deadline and not self.stop:
            self._pump(deadline)
        if not self.alive.any():
            raise RuntimeError(f"no robot came alive within {self.run_cfg.start_timeout:g} s")

    def _pump(self, deadline: float, tick: tuple[int, int] | None = None,
              inbox: dict[str, dict[int, Any]] | None = None) -> bool:
        """Handle one queued event (or due delivery) before `deadline`; False when it passed."""
        self._flush_due()
        wait_until = min(deadline, self._due[0][0]) if self._due else deadline
        try:
            kind, key, payload = self.q.get(timeout=max(0.0, wait_until - time.monotonic()))
        except queue.Empty:
            self._flush_due()
            return time.monotonic() < deadline
        if kind in ("live", "dead"):
            self._liveness(kind, key)
            return True
        if kind == "control":
            try:
                rec = unpack_record(payload or b"", K_CONTROL)
            except BadMessage as exc:
                self._count_bad(key, str(exc))
                return True
            if rec.get("stop"):
                self.stop = True
            if isinstance(rec.get("faults_table"), dict):
                table = rec["faults_table"] if rec.get("replace") else {
                    **self.fault_table, **rec["faults_table"]}
                table = {k: v for k, v in table.items() if k not in ("crash", "hang", "restart")}
                try:
                    self._pending_plan = plan_from_table(table, self.run_cfg.seed)
                    self.fault_table = table
                except ConfigError as exc:
                    self._count_bad(key, str(exc))
            return True
        if tick is None or inbox is None:
            return True
        try:
            if kind == "traj":
                msg: Any = Traj.unpack(payload or b"", self.cfg)
            elif kind == "hidden":
                msg = Hidden.unpack(payload or b"", self.cfg)
            else:
                msg = Action.unpack(payload or b"", self.cfg)
            if Keys.robot_of(key) != msg.robot:
                raise BadMessage(f"robot id {msg.robot} does not match key")
        except (BadMessage, ValueError) as exc:
            self._count_bad(key, str(exc))
            return True
        if (msg.ep, msg.t) != tick:
            self.late += 1
            return True
        if kind == "traj":
            self.radio.counters.traj_in += 1
            self.radio.counters.bytes_in += len(payload or b"")
            inbox["traj"][msg.robot] = (payload, time.monotonic())
        elif kind == "hidden":
            self.radio.counters.hidden_in += 1
            if inbox.get("delivered"):
                self._forward_hidden(msg, payload or b"", inbox)
            else:
                inbox["hidden"][msg.robot] = (msg, payload)
        else:
            inbox["action"][msg.robot] = msg
        return True

    def _schedule(self, when: float, key: str, payload: bytes) -> None:
        if when <= time.monotonic():
            self._put(key, payload)
        else:
            self._seq += 1
            heapq.heappush(self._due, (when, self._seq, key, payload))

    def _flush_due(self) -> None:
        now = time.monotonic()
        while self._due and self._due[0][0] <= now:
            _, _, key, payload = heapq.heappop(self._due)
            self._put(key, payload)

    def _forward_hidden(self, msg: Hidden, payload: bytes, inbox: dict[str, Any]) -> None:
        for i, when in self.radio.hidden_deliveries(msg.ep, msg.t, msg.robot, len(payload),
                                                    time.monotonic(), inbox["hidden_deadline"]):
            self._schedule(when, self.keys.inbox_hidden(i), payload)
            self.radio.counters.hidden_delivered += 1

    def _deliver(self, state: core.WorldState, ep: int, t: int, inbox: dict[str, Any]) -> None:
        lay = core.Layout.of(self.cfg)
        bundles = self.radio.bundles(ep, t, lay.to_yx(state.pos[0]), inbox["traj"],
                                     inbox["traj_deadline"])
        for i, (when, payloads) in bundles.items():
            self._schedule(when, self.keys.inbox(i), Bundle(ep, t, i, payloads).pack())
        inbox["delivered"] = True
        for msg, payload in inbox["hidden"].values():
            self._forward_hidden(msg, payload, inbox)

    def play_episode(self, ep: int) -> tuple[core.WorldState, list[np.ndarray], int]:
        cfg, keys = self.cfg, self.keys
        state = core.reset(cfg, self.run_cfg.seed, [ep])
        lay = core.Layout.of(cfg)
        actions_log: list[np.ndarray] = []
        rewards: list[np.ndarray] = []  # per tick, for the learner (run.train)
        acted: list[np.ndarray] = []
        ticks = 0
        next_tick = time.monotonic()
        while True:
            if self.run_cfg.pace > 0:
                time.sleep(max(0.0, next_tick - time.monotonic()))
                next_tick = max(next_tick, time.monotonic() - 1.0) + 1.0 / self.run_cfg.pace
            if self.parent is not None and os.getppid() != self.parent:
                log.warning("supervisor gone: stopping the run")
                self.stop = True
            if self._pending_plan is not None:
                self.radio.set_plan(self._pending_plan)
                log.info("faults now: %s", "; ".join(self._pending_plan.describe()) or "none")
                self._pending_plan = None
            self._due.clear()  # nothing of an older tick is ever delivered
            state.alive[0] = self.alive
            t = state.t
            yx = lay.to_yx(state.pos[0])
            patch = core.patches(cfg, state)[0]
            done = state.done
            start = time.monotonic()
            timeout = self.run_cfg.tick_timeout
            deadline = start + timeout
            budget_ms = 1e3 * timeout
            for i in np.flatnonzero(self.alive):
                self._put(keys.obs(int(i)), Obs(ep, t, int(i), int(yx[i, 0]), int(yx[i, 1]),
                                                 patch[i].tobytes(), float(state.last_reward[0, i]),
                                                 bool(done), budget_ms).pack())
            if done and self.run_cfg.train and rewards:
                m = core.metrics(cfg, state)
                rec = EpisodeRecord(ep, np.stack(rewards).astype(np.float32), np.stack(acted),
                                    {k: float(getattr(m, k)[0]) for k in METRIC_NAMES})
                self._put(keys.episode, rec.pack())
            if done or self.stop:
                return state, actions_log, ticks
            traj_deadline = start + timeout / 2  # the radio stops waiting for senders
            inbox: dict[str, Any] = {"traj": {}, "hidden": {}, "action": {}, "delivered": False,
                                     "traj_deadline": start + 0.8 * timeout,
                                     "hidden_deadline": start + 0.9 * timeout}
            while True:
                live = set(np.flatnonzero(self.alive).tolist())
                if not inbox["delivered"] and (live <= set(inbox["traj"])
                                               or time.monotonic() >= traj_deadline):
                    self._deliver(state, ep, t, inbox)
                if inbox["delivered"] and live <= set(inbox["action"]):
                    break
                if self.stop or not self.alive.any():
                    break
                limit = deadline if inbox["delivered"] else min(deadline, traj_deadline)
                if not self._pump(limit, (ep, t), inbox) and time.monotonic() >= deadline:
                    break
            acts = np.zeros((1, cfg.n_robots), dtype=np.int64)
            for i, msg in inbox["action"].items():
                acts[0, i] = msg.action
            self.planning_ms += sum(m.planning_ms for m in inbox["action"].values())
            missing = [int(i) for i in np.flatnonzero(self.alive) if i not in inbox["action"]]
            self.timeouts += len(missing)
            state.alive[0] = self.alive
            reward = core.step(cfg, state, acts)
            if self.run_cfg.train:
                rewards.append(np.asarray(reward)[0].copy())
                did = np.zeros(cfg.n_robots, dtype=bool)
                did[list(inbox["action"])] = True
                acted.append(did & self.alive)
            actions_log.append(acts[0].copy())
            ticks += 1
            self.run_tick += 1
            self._status(state, ep, missing)

    def _status(self, state: core.WorldState, ep: int, missing: list[int]) -> None:
        lay = core.Layout.of(self.cfg)
        rec = {
            "ep": ep, "t": state.t, "pos": lay.to_yx(state.pos[0]).tolist(),
            "alive": self.alive.tolist(), "elratio": float(state.elratio[0, state.t]),
            "block_coll": int(state.block_coll.sum()), "robot_coll": int(state.robot_coll.sum()),
            "dyn": lay.to_yx(state.dyn_cells[0][state.dyn_active[0]]).tolist(),
            "timeouts": missing, "bad": sum(self.bad.values()), "late": self.late,
            "run_tick": self.run_tick, "wall": time.time(), "radio": self.radio.counters.totals(),
            "faults": self.radio.plan.describe(),
            "links": {f"{a}-{b}": [s.delivered, s.lost + s.cut + s.dropped_bw, s.late, s.queued]
                      for (a, b), s in self.radio.counters.links.items()
                      if s.lost or s.cut or s.late or s.queued or s.dropped_bw},
        }
        if state.t == 1:
            rec["static"] = np.argwhere(lay.inner(state.grid[0]) == core.STATIC).tolist()
        if self.on_status is not None:
            self.on_status(rec)
        self._put(self.keys.status, pack_record(K_STATUS, rec))

    def run(self) -> dict[str, Any]:
        ents = self._declare()
        try:
            self.wait_for_robots()
            parts, curves, actions = [], [], []
            ticks, t0 = 0, time.monotonic()
            rc = self.run_cfg
            for ep in range(rc.first_episode, rc.first_episode + rc.episodes):
                state, acts, n = self.play_episode(ep)
                ticks += n
                if self.stop:
                    break
                parts.append(core.metrics(self.cfg, state))
                curves.append(state.elratio)
                actions.append(np.array(acts).tolist())
            wall = time.monotonic() - t0
            result = self._result(parts, curves, actions, ticks, wall)
            self._put(self.keys.result, pack_record(K_RESULT, result))
            time.sleep(0.05)  # let the result leave before the session closes
            if rc.train:  # robots' and learner's traffic is routed through this session:
                # stay up until the supervisor has let the learner take the last episodes
                deadline = time.monotonic() + 15.0
                while not self.stop and self._pump(deadline):
                    pass
            return result
        finally:
            for e in ents:
                e.undeclare()

    def _result(self, parts: list[core.EpisodeMetrics], curves: list[np.ndarray],
                actions: list[Any], ticks: int, wall: float) -> dict[str, Any]:
        rc = self.run_cfg
        out: dict[str, Any] = {"policy": rc.policy, "run_id": rc.run_id, "completed": len(parts)}
        if parts:
            cat = lambda name: np.concatenate([getattr(m, name) for m in parts])  # noqa: E731
            res = EvalResult(
                policy=rc.policy, seed=rc.seed,
                episodes=np.arange(rc.first_episode, rc.first_episode + len(parts)),
                reward=cat("reward"), collisions=cat("collisions"),
                block_collisions=cat("block_collisions"), robot_collisions=cat("robot_collisions"),
                elratio=cat("elratio"), success=cat("success"), repeat_ratio=cat("repeat_ratio"),
                elratio_curve=np.concatenate(curves), wall_s=wall)
            out.update(res.summary(self.cfg))
            # per team decision: the robots' planning times of a tick, summed (they run in
            # parallel processes, so this is CPU work, not latency)
            out["planning_ms_per_decision"] = self.planning_ms / max(self.run_tick, 1)
        c = self.radio.counters
        messages = c.totals()
        messages["late"] += self.late  # radio-late copies + messages of an older tick
        out.update({
            "ticks": ticks, "ticks_per_s": ticks / wall if wall > 0 else 0.0,
            "messages": {**messages, "bad": sum(self.bad.values()), "bad_by_key": dict(self.bad)},
            "faults": self.radio.plan.to_record(),
            "timeouts": self.timeouts,
            "robots_lost": int((self.ever_alive & ~self.alive).sum()),
            "actions": actions,
        })
        return out


def main(cfg: WorldConfig, run: RunConfig, zopts: ZenohOptions,
         on_status: Callable[[dict[str, Any]], None] | None = None,
         faults: dict[str, Any] | None = None, watch_parent: bool = False) -> dict[str, Any]:
    """Open a session, play the run, return its result record."""
    with zenoh.open(zopts.to_config()) as session:
        world = WorldProcess(cfg, run, session, on_status, faults)
        if watch_parent:
            world.parent = os.getppid()
        return world.run()
