"""`swarm replay FILE --verify`: audit a recording by recomputing it.

The world is re-stepped from the recorded run record with the recorded actions, by the world
process's own functions (`world.core.reset/step/patches/metrics`, `EvalResult.of` for the
result): every observation, every status and the result must be what they compute. A recording
made in virtual time also re-runs the radio (`swarm.net.radio.Radio` with its `VirtualChannel`,
live fault changes included) on the recorded trajectory and hidden-state messages: every
bundle, every forwarded hidden-state message (or miss marker) and the radio's counters must
match; under direct delivery the robots' own deliveries are re-run instead
(`swarm.studies.verify_direct`). Every JSON form (a `/json` channel) must be the one of the raw
payload beside it (`check_json_forms`). The first divergence is reported as (episode, tick,
field, recorded, recomputed).

Which actions the world applied, and which messages its radio saw, cannot be read from the
order the recorder heard them in: the world, the run's router, may step and publish its status
before it forwards the last action to the recorder. So: the world applied every recorded action
of tick t from a robot that its status does not list as timed out (the status is checked to
list exactly the live robots without one); its radio saw the trajectory message of every robot
it sent a bundle to (it always hands a sender its own message back) and the hidden-state
message of every robot that did not time out. Unreadable payloads (a foreign peer's garbage)
are skipped and counted, not divergences: every live process dropped them; so are strays the
world dropped (an action before its robot's observation, a status out of order). A partial
recording (`--partial`) is checked up to the tick before its last status.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm.learn.evaluate import EvalResult
from swarm.net.faults import plan_from_table
from swarm.net.faults.control import MAX_PENDING, Control, changed_table, check_control
from swarm.net.messages import (
    K_CONTROL,
    K_STATUS,
    Action,
    BadMessage,
    Bundle,
    Hidden,
    Obs,
    Stamped,
    Traj,
    unpack_record,
)
from swarm.net.radio import Radio
from swarm.net.record.recording import check_json_forms
from swarm.net.records import check_world_status
from swarm.procs.status_order import in_order
from swarm.studies.replay import Recording, recorded_result
from swarm.studies.verify_direct import DirectAudit, hidden_label, reported, senders_of, stamped_of
from world import core
from world.config import ConfigError

SUMMARY_KEYS = ("elratio_mean", "elratio_std", "reward_mean", "reward_std", "collisions_mean",
                "block_collisions_mean", "robot_collisions_mean", "success_rate",
                "repeat_ratio_mean")
RADIO_KEYS = ("out_of_range", "lost", "cut", "late", "queued", "dropped_bw", "traj_delivered",
              "hidden_delivered", "bytes_out")
UNPACK = {"obs": Obs, "traj": Traj, "bundle": Bundle, "hidden": Hidden, "radio_hidden": Hidden,
          "action": Action}


@dataclass
class Divergence:
    ep: int
    t: int
    run_tick: int
    field: str
    recorded: Any
    recomputed: Any

    def line(self) -> str:
        short = lambda x: (s if len(s := repr(x)) <= 120 else s[:117] + "...")  # noqa: E731
        return (f"divergence at episode {self.ep} tick {self.t} (run tick {self.run_tick}): "
                f"{self.field}: recorded {short(self.recorded)}, recomputed "
                f"{short(self.recomputed)}")


@dataclass
class VerifyReport:
    checked: dict[str, int] = field(default_factory=dict)
    divergence: Divergence | None = None
    notes: list[str] = field(default_factory=list)
    ticks: int = 0
    unreadable: int = 0  # payloads skipped: every live process dropped them

    def count(self, what: str, n: int = 1) -> None:
        self.checked[what] = self.checked.get(what, 0) + n


class _Diverged(Exception):
    pass


@dataclass
class _Tick:
    """The recorded messages of one (episode, tick), with their position in the recording."""

    obs: list[tuple[int, Obs]] = field(default_factory=list)
    traj: list[tuple[int, Traj, bytes]] = field(default_factory=list)
    bundle: list[tuple[int, Bundle]] = field(default_factory=list)
    hidden: list[tuple[int, Hidden, bytes]] = field(default_factory=list)
    radio_hidden: list[tuple[int, Hidden, bytes]] = field(default_factory=list)
    action: list[tuple[int, Action]] = field(default_factory=list)
    direct: list[tuple[str, Stamped, bytes]] = field(default_factory=list)  # (key, it, raw)


def _index(rec: Recording, report: VerifyReport) -> tuple[dict[tuple[int, int], _Tick],
                                                           dict[tuple[int, int], tuple[int, dict]],
                                                           list[tuple[int, dict]]]:
    cfg, run = rec.record.world, rec.record.run
    ticks: dict[tuple[int, int], _Tick] = {}
    status: dict[tuple[int, int], tuple[int, dict]] = {}
    control: list[tuple[int, dict]] = []
    statuses: list[tuple[int, dict]] = []  # (taken in order at the end)
    for idx, m in enumerate(rec.messages):
        try:
            if m.kind == "status":  # (checked as the supervisor checks it)
                statuses.append((idx, check_world_status(unpack_record(
                    m.payload, K_STATUS), cfg, run.first_episode, run.episodes)))
                continue
            if m.kind == "control":
                control.append((idx, unpack_record(m.payload, K_CONTROL)))
                continue
            if m.kind == "direct":
                st = stamped_of(m.key, m.payload, m.robot, cfg)
                ticks.setdefault((st.ep, st.t), _Tick()).direct.append((m.key, st, m.payload))
                continue
            if m.kind not in UNPACK:
                continue
            msg = UNPACK[m.kind].unpack(m.payload, cfg)
            if m.kind not in ("bundle", "radio_hidden", "obs") and msg.robot != m.robot:
                raise BadMessage("robot id does not match the key")
        except (BadMessage, KeyError, TypeError, ValueError, OverflowError):
            report.unreadable += 1
            continue
        bucket = ticks.setdefault((msg.ep, msg.t), _Tick())
        if m.kind in ("traj", "hidden", "radio_hidden"):
            getattr(bucket, m.kind).append((idx, msg, m.payload))
        elif m.kind == "bundle" and msg.robot == m.robot:
            bucket.bundle.append((idx, msg))
        elif m.kind == "obs" and msg.robot == m.robot:
            bucket.obs.append((idx, msg))
        elif m.kind == "action":
            bucket.action.append((idx, msg))
    for idx, st in in_order(statuses):  # as the supervisor takes them (a stray: not)
        status.setdefault((int(st["ep"]), int(st["t"])), (idx, st))
    return ticks, status, control


class Auditor:
    """Re-steps one recording; `run()` returns the report (stops at the first divergence)."""

    def __init__(self, rec: Recording) -> None:
        self.rec, self.cfg, self.run = rec, rec.record.world, rec.record.run
        self.report = VerifyReport()
        self.virtual = self.run.clock == "virtual"
        # direct delivery: robots decide their copies' fates themselves and the world's radio
        # does not run, so the robots' own decisions are re-run
        self.radio_run = self.virtual and getattr(self.run, "delivery", "radio") == "radio"
        self.table = dict(rec.record.faults)
        self.direct = DirectAudit(self.cfg, self.run, self.table) if self.virtual and \
            not self.radio_run else None
        self.direct_links = 0  # direct delivery: the links the actions say were heard
        self.radio = Radio(self.cfg, plan_from_table(self.table, self.run.seed, self.cfg.n_robots))
        if self.virtual:
            self.radio.use_virtual_clock(self.run.tick_timeout)
        self.hidden_delivered = 0
        self.where = (0, 0, 0)

    def fail(self, what: str, recorded: Any, recomputed: Any) -> None:
        self.report.divergence = Divergence(*self.where, what, recorded, recomputed)
        raise _Diverged

    def same(self, what: str, recorded: Any, recomputed: Any) -> None:
        ok = (math.isclose(recorded, recomputed, rel_tol=1e-9, abs_tol=1e-12)
              if isinstance(recorded, float) and isinstance(recomputed, float)
              and not isinstance(recorded, bool) else recorded == recomputed)
        if not ok:
            if isinstance(recorded, list) and isinstance(recomputed, list) and \
                    len(recorded) == len(recomputed):  # name the first element that differs
                k = next(k for k, (a, b) in enumerate(zip(recorded, recomputed, strict=True))
                         if a != b)
                self.fail(f"{what}[{k}]", recorded[k], recomputed[k])
            self.fail(what, recorded, recomputed)

    def run_audit(self) -> VerifyReport:
        ticks, status, control = _index(self.rec, self.report)
        try:
            self.result = self._recorded_result()
        except _Diverged:
            return self.report
        if not self.rec.raw.complete and status and self.result is None:  # the cut may have
            # lost the last tick's messages (with the result in, the run had ended before it)
            last = max(status, key=lambda k: status[k][0])
            del status[last]
            self.report.notes.append(f"partial recording: episode {last[0]} tick {last[1] - 1}, "
                                     "the last with a status, is not checked (the cut may have "
                                     "lost some of its messages)")
        self.ticks, self.status, self.control = ticks, status, control
        # the changes the world took: the same whole-record check (a record it dropped, a stop
        # beside a bad table for one, changes nothing here either), in its order: by the tick
        # asked for, then arrival; one without a tick is placed by the status showing it
        self.pending: list[tuple[int, Control]] = []
        for idx, rec in control:
            try:
                ctl = check_control(rec, self.run.seed, self.cfg.n_robots)
            except ConfigError:
                continue
            if ctl.table is not None and len(self.pending) < MAX_PENDING:
                self.pending.append((idx, ctl))
        self.pending.sort(key=lambda item: (item[1].at_tick if item[1].at_tick >= 0 else 2**62,
                                            item[0]))
        if not self.virtual:
            self.report.notes.append("real clock: deliveries depend on wall time; the radio is "
                                     "not re-run, the world is")
        try:
            self._episodes()
            self._result()
            self._json_forms()
        except _Diverged:
            pass
        return self.report

    def _episodes(self) -> None:
        r = self.run
        self.parts: list[core.EpisodeMetrics] = []
        self.curves: list[np.ndarray] = []
        self.actions: list[list[list[int]]] = []
        self.timeouts = 0
        self.acted: dict[int, int] = {}  # robot -> recording index of the last action taken
        run_tick = 0
        for ep in range(r.first_episode, r.first_episode + r.episodes):
            if (ep, 1) not in self.status:
                break  # the run (or the recording) ended before this episode
            state = core.reset(self.cfg, r.seed, [ep])
            self.radio.new_episode()
            acts_log = []
            while not state.done and (ep, state.t + 1) in self.status:
                self.where = (ep, state.t, run_tick)
                acts_log.append(self._tick(ep, state, run_tick))
                run_tick += 1
                self.report.ticks += 1
            if state.done:
                self.where = (ep, state.t, run_tick)
                self._observations(ep, state)
                if self.direct is not None:  # a live change may ride in the last observations
                    self.direct.faults({o.robot: o for _, o in
                                        self.ticks.get((ep, state.t), _Tick()).obs})
                self.parts.append(core.metrics(self.cfg, state))
                self.curves.append(state.elratio)
                self.actions.append(acts_log)

    def _apply_fault_changes(self, run_tick: int, ep: int, t: int) -> None:
        """Live `swarm fault` changes: from their `at_tick`, else the tick whose status shows it."""
        st = self.status.get((ep, t + 1), (0, {}))[1]
        for item in list(self.pending):
            _, ctl = item
            table = changed_table(self.table, ctl)
            try:
                plan = plan_from_table(table, self.run.seed, self.cfg.n_robots)
            except ConfigError:
                if ctl.at_tick >= 0 and run_tick >= ctl.at_tick:
                    self.pending.remove(item)  # unfit merged onto the table in force: dropped
                continue
            due = run_tick >= ctl.at_tick if ctl.at_tick >= 0 else \
                st.get("faults") == plan.panel()
            if due:
                self.pending.remove(item)
                self.table = table
                self.radio.set_plan(plan)

    def _observations(self, ep: int, state: core.WorldState) -> None:
        lay = core.Layout.of(self.cfg)
        yx = lay.to_yx(state.pos[0])
        patch = core.patches(self.cfg, state)[0]
        for _, o in self.ticks.get((ep, state.t), _Tick()).obs:
            i = o.robot
            self.same(f"obs[{i}].pos", [o.y, o.x], yx[i].tolist())
            self.same(f"obs[{i}].patch", list(o.patch), patch[i].ravel().tolist())
            self.same(f"obs[{i}].reward", o.reward, float(state.last_reward[0, i]))
            self.same(f"obs[{i}].done", o.done, bool(state.done))
            self.report.count("observations")

    def _tick(self, ep: int, state: core.WorldState, run_tick: int) -> list[int]:
        cfg, t = self.cfg, state.t
        self._apply_fault_changes(run_tick, ep, t)
        st = self.status[(ep, t + 1)][1]
        bucket = self.ticks.get((ep, t), _Tick())
        seen = [o.robot for _, o in bucket.obs]
        if seen:  # the world observes exactly the robots it holds alive at the tick's start (a
            # process fault of this tick, or a restarted robot it waited for, changed them)
            state.alive[0] = np.isin(np.arange(cfg.n_robots), seen)
        self._observations(ep, state)
        late = st.get("timeouts")
        if not isinstance(late, list) or not all(isinstance(i, int) and 0 <= i < cfg.n_robots
                                                 for i in late):
            self.fail("status.timeouts", late, "a list of robot ids")
        if self.radio_run:
            self._radio(ep, t, state, bucket, set(late))
        elif self.direct is not None:
            obs = {o.robot: o for _, o in bucket.obs}
            self.report.count("direct copies decided", self.direct.tick(obs, bucket.direct,
                                                                        self.same))
            self._heard(bucket, set(late))
        alive = np.zeros(cfg.n_robots, dtype=bool)
        rec_alive = st.get("alive")
        if not isinstance(rec_alive, list) or len(rec_alive) != cfg.n_robots:
            self.fail("status.alive", rec_alive, f"{cfg.n_robots} flags")
        alive[:] = [bool(a) for a in rec_alive]
        acts = np.zeros((1, cfg.n_robots), dtype=np.int64)
        got, seen = set(), {o.robot: i for i, o in reversed(bucket.obs)}  # (a stray: before)
        for idx, a in bucket.action:  # a timed-out robot's action came after the deadline
            if a.robot not in late and a.robot not in got and \
                    idx > max(self.acted.get(a.robot, -1), seen.get(a.robot, -1)):
                acts[0, a.robot] = a.action
                got.add(a.robot)
                self.acted[a.robot] = idx
        # the world waits for the robots it sent this tick's observation to (one that came
        # alive mid-tick joins at the next); those still alive without an action timed out
        sent = {o.robot for _, o in bucket.obs}
        missing = [int(i) for i in np.flatnonzero(alive) if i in sent and i not in got]
        self.same("status.timeouts (alive robots observed without a recorded action)", late,
                  missing)
        self.timeouts += len(missing)
        self.report.count("actions", len(got))
        state.alive[0] = alive
        core.step(cfg, state, acts)
        self._status(st, state)
        return acts[0].tolist()

    def _heard(self, bucket: _Tick, late: set[int]) -> None:
        """Direct delivery: whom a robot says it heard (`Action.heard`) its re-run link hears."""
        n = self.cfg.n_robots
        rows = np.zeros((n, n), dtype=bool)
        for _, a in bucket.action:
            if not a.heard or a.robot in late:
                continue
            row = np.unpackbits(np.frombuffer(a.heard, dtype=np.uint8), count=n).astype(bool)
            self.same(f"robot {a.robot}'s heard senders (action)", np.flatnonzero(row).tolist(),
                      self.direct.heard.get(a.robot) if self.direct is not None else None)
            rows[a.robot] = row
        self.direct_links = int(np.triu(rows | rows.T, 1).sum())

    def _status(self, st: dict, state: core.WorldState) -> None:
        lay = core.Layout.of(self.cfg)
        self.same("status.pos", st.get("pos"), lay.to_yx(state.pos[0]).tolist())
        self.same("status.elratio", st.get("elratio"), float(state.elratio[0, state.t]))
        self.same("status.block_coll", st.get("block_coll"), int(state.block_coll.sum()))
        self.same("status.robot_coll", st.get("robot_coll"), int(state.robot_coll.sum()))
        self.same("status.dyn", st.get("dyn"),
                  lay.to_yx(state.dyn_cells[0][state.dyn_active[0]]).tolist())
        if state.t == 1:
            self.same("status.static", st.get("static"),
                      np.argwhere(lay.inner(state.grid[0]) == core.STATIC).tolist())
        if self.radio_run:
            self.same("status.heard_links", st.get("heard_links"), self.radio.heard_links())
            radio = st.get("radio") if isinstance(st.get("radio"), dict) else {}
            for k, v in self._radio_totals().items():
                self.same(f"status.radio.{k}", radio.get(k), v)
            self.same("status.links", st.get("links"), self._links())
        elif self.direct is not None:
            self.same("status.heard_links", st.get("heard_links"), self.direct_links)
        self.report.count("statuses")

    def _radio_totals(self) -> dict[str, Any]:
        tot = self.radio.counters.totals()
        tot["hidden_delivered"] = self.hidden_delivered
        return {k: tot[k] for k in RADIO_KEYS} | {"by_kind": tot["by_kind"]}

    def _links(self) -> dict[str, list[int]]:
        return self.radio.counters.faulted_links()

    def _radio(self, ep: int, t: int, state: core.WorldState, bucket: _Tick,
               late: set[int]) -> None:
        """The radio's decisions of this tick from the messages it saw, against what it sent."""
        lay = core.Layout.of(self.cfg)
        trajs = {tr.robot: payload for _, tr, payload in bucket.traj}
        senders: dict[int, bytes] = {}
        for i in sorted({b.robot for _, b in bucket.bundle}):
            if i not in trajs:
                self.fail(f"trajectory message of robot {i}", None, "the one its bundle holds")
            senders[i] = trajs[i]
        if not senders:
            return
        want = self.radio.virtual_bundles(ep, t, lay.to_yx(state.pos[0]), senders)
        got = {b.robot: b.trajs for _, b in bucket.bundle}
        for i in sorted(set(want) | set(got)):
            self.same(f"bundle to robot {i} (senders)",
                      senders_of(got.get(i), self.cfg), senders_of(want.get(i), self.cfg))
            self.same(f"bundle to robot {i}", got.get(i), want.get(i))
            self.report.count("bundles")
            self.report.count("deliveries", len(want.get(i) or []))
        succ = {b.robot: b.succ for _, b in bucket.bundle}
        if any(v is not None for v in succ.values()):
            self._fast_lane(bucket, succ, late)
            return
        expect: list[tuple[int, bytes]] = []
        for _, h, payload in bucket.hidden:
            if h.robot not in late:
                for i, on_time in self.radio.virtual_hidden(ep, t, h.robot, len(payload)):
                    expect.append((i, payload if on_time else Hidden.miss(ep, t, h.robot).pack()))
                    self.hidden_delivered += on_time
        forwarded = sorted((self._receiver(idx), p) for idx, _, p in bucket.radio_hidden)
        self.same("hidden-state messages forwarded (receiver, sender:state digest)",
                  [(i, hidden_label(p, self.cfg)) for i, p in forwarded],
                  [(i, hidden_label(p, self.cfg)) for i, p in sorted(expect)])
        self.report.count("hidden forwarded", len(expect))

    def _fast_lane(self, bucket: _Tick, succ: dict[int, list[int] | None],
                   late: set[int]) -> None:
        """A fast-lane tick (no link fault): each bundle named its robot's successors, and each
        robot that acted sent its hidden-state message to exactly those, nothing via the radio."""
        if not self.radio.plan.zero:
            self.fail("bundles naming successors", "a tick with link faults", "no link fault")
        expect: list[tuple[int, int]] = []
        for j in sorted(succ):
            want = self.radio.successors(j)
            self.same(f"bundle to robot {j} (successors)", succ[j], want)
            if j not in late:
                expect += [(i, j) for i in want]
                self.hidden_delivered += len(want)
        sent = sorted((self._receiver(idx), h.robot) for idx, h, _ in bucket.radio_hidden
                      if h.robot not in late)  # (one that never acted may have sent them)
        self.same("hidden-state messages sent to successors (receiver, sender)", sent,
                  sorted(expect))
        self.same("hidden-state messages to the radio on a fast-lane tick", len(bucket.hidden), 0)
        self.report.count("hidden forwarded", len(expect))

    def _receiver(self, idx: int) -> int:
        robot = self.rec.messages[idx].robot
        return -1 if robot is None else robot

    def _recorded_result(self) -> dict[str, Any] | None:
        res, bad, note, skipped = recorded_result(self.rec)
        self.report.notes += [note] if note else []
        self.report.unreadable += skipped
        if bad is not None:  # (at the recording's last run tick: its end)
            k, t = max(bad[3] - 1, 0), self.cfg.horizon
            self.where = (self.run.first_episode + k // t, k % t + 1, bad[3])
            self.fail(*bad[:3])
        return res

    def _result(self) -> None:
        res = self.result
        if res is None:
            self.report.notes.append("no result recorded (the recording ended before the run's "
                                     "end): the result was not checked")
            return
        r = self.run
        n = len(self.parts)
        self.where = (r.first_episode + max(n - 1, 0), self.cfg.horizon, self.report.ticks)
        self.same("result.completed", res.get("completed"), n)
        self.same("result.ticks", res.get("ticks"), self.report.ticks)
        self.same("result.timeouts", res.get("timeouts"), self.timeouts)
        rec_actions = res.get("actions")
        for e, acts in enumerate(self.actions):
            for t, row in enumerate(acts):
                try:
                    recorded = rec_actions[e][t]  # type: ignore[index]
                except (TypeError, IndexError, KeyError):
                    recorded = None
                if recorded != row:
                    self.where = (r.first_episode + e, t, e * self.cfg.horizon + t)
                    self.fail("result.actions (the action messages)", recorded, row)
        if n:
            summ = EvalResult.of(r.policy, r.seed, np.arange(r.first_episode, r.first_episode + n),
                                 self.parts, self.curves).summary(self.cfg)
            for k in SUMMARY_KEYS:
                self.same(f"result.{k}", res.get(k), float(summ[k]))  # type: ignore[arg-type]
        msgs = res.get("messages") if isinstance(res.get("messages"), dict) else {}
        try:
            mine = self._radio_totals() if self.radio_run else self.direct.totals(
                msgs.get("restarted"), reported(self.rec)) if self.direct is not None else {}
        except BadMessage as exc:  # a crashed robot's report the recording cannot place
            self.fail("result.messages.restarted", msgs.get("restarted"), str(exc))
            return
        for k, v in mine.items():
            self.same(f"result.messages.{k}", msgs.get(k), v)
        self.report.count("results")

    def _json_forms(self) -> None:
        """Every `/json` message is the JSON form of the raw payload beside it (Foxglove's)."""
        checked, bad = check_json_forms(self.rec.raw, self.cfg)
        if bad is not None:
            what, tick, (ep, t), recorded, expected = bad
            if not (type(ep) is int and type(t) is int):  # (a kind that names no tick)
                ep, t = self.run.first_episode + tick // self.cfg.horizon, tick % self.cfg.horizon
            self.where = (ep, t, tick)
            self.fail(what, recorded, expected)
        self.report.count("JSON forms", checked)


def verify(rec: Recording) -> VerifyReport:
    """Audit `rec` (see the module docstring)."""
    return Auditor(rec).run_audit()
