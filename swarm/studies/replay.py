"""`swarm replay FILE`: a recording (`swarm.net.record.recording`) checked against its own run and
played back through the live dashboard (`swarm.procs.dashboard`), with no network.

`load` turns a file into a `Recording`: the run's `RunRecord` from its attachment, every raw
message with its kind and robot id, and the result when the recording finished. A file whose
channels are not all keys of its run (another run's keys, robots outside the team), or without
a readable run record, is a one-line `RecordingError`. `replay` feeds the world and robot
status records to a `SwarmView` at the recorded pace (scaled by `speed`; 0: as fast as it
goes), fast-forwarding to `from_tick`; every record is validated as the supervisor would, and
one that does not fit is dropped and counted.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live

from swarm.net.faults import ProcessFault, parse_process
from swarm.net.keys import Keys
from swarm.net.learning import check_learner_status
from swarm.net.messages import (
    K_CONTROL,
    K_LSTATUS,
    K_RESULT,
    K_RSTATUS,
    K_STATUS,
    BadMessage,
    unpack_record,
)
from swarm.net.record.recording import JSON_SUFFIX, RESULT, RUN_RECORD, RawRecording, RecordingError
from swarm.net.record.recording import read as read_file
from swarm.net.records import check_robot_status, check_world_result, check_world_status
from swarm.procs.dashboard import SwarmView, render
from swarm.procs.runconfig import RunRecord
from swarm.procs.status_order import StatusOrder
from world.config import ConfigError


@dataclass
class Msg:
    """One recorded payload: receipt wall time and virtual time (ns), run tick, key, kind."""

    wall_ns: int
    vtime_ns: int
    tick: int
    key: str
    kind: str
    robot: int | None
    payload: bytes


@dataclass
class Recording:
    path: str
    raw: RawRecording
    record: RunRecord
    result: dict[str, Any] | None
    messages: list[Msg]

    @property
    def last_tick(self) -> int:
        return max((m.tick for m in self.messages), default=0)

    def of(self, *kinds: str) -> list[Msg]:
        return [m for m in self.messages if m.kind in kinds]


def load(path: str | Path, partial: bool = False) -> Recording:
    """Read and check a recording against its own run (see the module docstring)."""
    raw = read_file(path, partial)
    where = f"{raw.path}: run record"
    rec_obj = raw.attachment(RUN_RECORD)
    if rec_obj is None:
        raise RecordingError(f"{raw.path} has no {RUN_RECORD} attachment")
    try:
        record = RunRecord.from_record(rec_obj, where)
    except ConfigError as exc:
        raise RecordingError(str(exc)) from None
    run_id = raw.meta.get("run_id", "")
    if run_id != record.run.run_id:
        raise RecordingError(f"{raw.path}: metadata names run {run_id!r}, its run record "
                             f"{record.run.run_id!r}")
    keys, n = Keys(run_id), record.world.n_robots
    owned: dict[str, tuple[str, int | None]] = {}
    for topic in [*raw.keys, *(t[:-len(JSON_SUFFIX)] for t in raw.json_topics)]:
        kind, robot = keys.kind_of(topic)
        if not kind or (robot is not None and robot >= n):
            raise RecordingError(f"{raw.path}: channel {topic!r} is not a key of run {run_id} "
                                 f"({n} robots)")
        owned[topic] = (kind, robot)
    result = raw.attachment(RESULT)
    if result is not None and not isinstance(result, dict):
        raise RecordingError(f"{raw.path}: {RESULT} is not a record")
    msgs = [Msg(m.wall_ns, m.vtime_ns, m.tick, m.key, *owned[m.key], m.payload)
            for m in raw.messages]
    return Recording(raw.path, raw, record, result, msgs)


def check_result(rec: Recording, result: dict[str, Any]) -> dict[str, Any]:
    """`result` as the run's supervisor checks it (BadMessage: it refused it)."""
    r = rec.record.run
    return check_world_result(result, r.policy, r.episodes, r.run_id, rec.record.world.horizon)


def recorded_result(rec: Recording) -> tuple[dict[str, Any] | None,
                                             tuple[str, Any, Any, int] | None, str | None, int]:
    """The world's result as recorded: its `world/result` message on the wire and the
    recorder's copy (`result.json`) must agree, and either stands alone when the other is
    missing. A `world/result` payload that is not a result record, or one the supervisor's
    check refuses (`check_result`), is skipped: the world never sends one (a foreign peer did)
    and the supervisor dropped it. (result, the first disagreement as (what, recorded,
    expected, run tick), a note, the payloads skipped)."""
    norm = lambda x: json.loads(json.dumps(x, default=str))  # noqa: E731 (inf, tuples)
    wire: dict[str, Any] | None = None
    skipped = 0
    for m in rec.of("result"):
        try:
            got = check_result(rec, unpack_record(m.payload, K_RESULT))
        except BadMessage:
            skipped += 1
            continue
        if wire is not None and norm(got) != norm(wire):
            return None, ("a second world/result message (as recorded) against the first (as "
                          "recomputed)", got, wire, m.tick), None, skipped
        wire = got
    copy, note = rec.result, None
    if copy is not None:
        try:
            check_result(rec, copy)
        except BadMessage as exc:  # the recorder keeps the last record on the key: a stray's
            copy, note = None, f"{RESULT} is not a result the supervisor takes ({exc}): left out"
    if wire is not None and copy is not None and norm(wire) != norm(copy):
        a, b = norm(copy), norm(wire)
        diff = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))[:3]
        return None, (f"{RESULT} (the recorder's copy, as recorded) against the world/result "
                      "message (as recomputed)",
                      {k: a.get(k) for k in diff}, {k: b.get(k) for k in diff},
                      rec.last_tick), None, skipped
    if copy is None and wire is not None:
        return wire, None, note or f"no {RESULT} attachment: the world/result message checked", \
            skipped
    return copy if copy is not None else wire, None, note, skipped


@dataclass
class ReplayStats:
    messages: int = 0  # replayed: those of ticks from `first_tick` on
    statuses: int = 0
    bad: int = 0  # records of the replayed ticks that did not fit their schema, dropped
    first_tick: int = 0
    last_tick: int = 0
    process_shown: int = 0  # the run's own process faults (its flags) put on the view so far
    planned: list[ProcessFault] | None = None  # those faults (read once from the run record)
    order: StatusOrder = field(default_factory=StatusOrder)  # a stray status is not shown


def run_process_faults(rec: Recording) -> list[ProcessFault]:
    """The process faults the run was started with (its `[faults]` crash, hang, restart), in
    order of tick; what does not parse is left out (the run refused it, or it is foreign)."""
    table, out = rec.record.faults or {}, []
    for kind in ("crash", "hang", "restart"):
        for text in table.get(kind, []) if isinstance(table.get(kind), list) else []:
            try:
                out.append(parse_process(kind, text))
            except ConfigError:
                continue
    return sorted(out, key=lambda f: f.tick)


def view_of(rec: Recording, attention: int | None = -1) -> SwarmView:
    w, r = rec.record.world, rec.record.run
    return SwarmView(r.run_id, r.policy, w.height, w.width, w.n_robots, w.comm_range, r.episodes,
                     attention_focus=attention)


def apply(v: SwarmView, m: Msg, stats: ReplayStats, rec: Recording) -> None:
    """One recorded message onto the view (records validated as the supervisor does)."""
    try:
        if m.kind == "status":
            w, r = rec.record.world, rec.record.run
            st = check_world_status(unpack_record(m.payload, K_STATUS), w, r.first_episode,
                                    r.episodes)
            take, dropped = stats.order.offer(st)  # as the supervisor takes them (a stray: not)
            if dropped is not None:
                _bad(stats, v, m)
            if take:
                _show_status(v, st, m, stats, rec)
        elif m.kind == "rstatus":
            w = rec.record.world
            v.apply_robot(check_robot_status(unpack_record(m.payload, K_RSTATUS), w.n_robots,
                                             w.horizon))
        elif m.kind == "control":
            ctl = unpack_record(m.payload, K_CONTROL)
            for text in ctl.get("process", [])[:16]:  # "crash:1" -> "crash 1@TICK", as live
                kind, _, robot = str(text).partition(":")
                v.events = v.events[-5:] + [f"{kind} {robot}@{v.ticks_done}" if "@" not in robot
                                            else f"{kind} {robot}"]
        elif m.kind == "lstatus":  # a --train run's learner panel, as live
            v.learner = check_learner_status(unpack_record(m.payload, K_LSTATUS))
        elif m.kind == "result":
            result = check_result(rec, unpack_record(m.payload, K_RESULT))
            held, dropped = stats.order.end(result.get("ticks"))
            if held is not None:  # (the last tick's status, after a skip, as live)
                _show_status(v, held, m, stats, rec)
            elif dropped is not None:
                _bad(stats, v, m)
            v.apply_result(result)
        elif m.kind == "end":
            v.world_alive = False
    except (BadMessage, TypeError, ValueError, KeyError, AttributeError, IndexError,
            OverflowError):
        _bad(stats, v, m)


def _bad(stats: ReplayStats, v: SwarmView, m: Msg) -> None:
    if m.tick >= stats.first_tick:  # (those fast-forwarded through are not replayed)
        stats.bad += 1
        v.bad_records = stats.bad


def _show_status(v: SwarmView, st: dict[str, Any], m: Msg, stats: ReplayStats,
                 rec: Recording) -> None:
    """A world status the supervisor would have applied, onto the view (with the run's own
    process faults due by its tick, as live)."""
    v.apply_status(st, now=m.wall_ns / 1e9)
    for i, alive in enumerate(st.get("alive", [])[: v.n_robots]):
        v.robots[i].alive = bool(alive)
        v.robots[i].state = "acting" if alive else "lost"
    v.world_alive = True
    stats.statuses += 1
    if stats.planned is None:  # `swarm run --crash 2@10`: at its tick, as live
        stats.planned = run_process_faults(rec)
    planned = stats.planned
    while stats.process_shown < len(planned) and \
            planned[stats.process_shown].tick <= int(st.get("run_tick", 0)):
        f = planned[stats.process_shown]
        v.events = v.events[-5:] + [f"{f.kind} {f.robot}@{f.tick}"]
        stats.process_shown += 1


def replay(rec: Recording, console: Console | None = None, speed: float = 1.0,
           from_tick: int = 0, until_tick: int | None = None, attention: int | None = -1,
           live: bool = True, sleep: Callable[[float], None] = time.sleep
           ) -> tuple[SwarmView, ReplayStats]:
    """Play `rec` on the dashboard; returns the final view and what was replayed."""
    v = view_of(rec, attention)
    stats = ReplayStats(first_tick=from_tick)
    name, total = Path(rec.path).name, rec.last_tick
    t0: int | None = None
    w0 = 0.0
    console = console or Console()
    screen = Live(get_renderable=lambda: render(v, console.is_terminal), console=console,
                  refresh_per_second=4, transient=False) if live else None
    if screen is not None:
        screen.start()
    try:
        for m in rec.messages:
            if until_tick is not None and m.tick > until_tick:
                continue  # (not break: one stray filed at a later tick ended the replay there)
            if m.tick >= from_tick and speed > 0:
                if t0 is None:
                    t0, w0 = m.wall_ns, time.monotonic()
                wait = w0 + (m.wall_ns - t0) / 1e9 / speed - time.monotonic()
                if wait > 5.0:  # a long silence in the recording is cut short to 5 s
                    w0 -= wait - 5.0  # (and the messages after it keep their pace from there)
                    wait = 5.0
                if wait > 1e-3:
                    sleep(wait)
            apply(v, m, stats, rec)
            v.elapsed_s = m.wall_ns / 1e9 - (v.first_status if v.first_status is not None
                                             else rec.messages[0].wall_ns / 1e9)
            if m.tick >= from_tick:  # (those before are fast-forwarded through, not replayed)
                stats.messages += 1
                stats.last_tick = max(stats.last_tick, m.tick)
            pace = "as fast as it goes" if speed <= 0 else f"x{speed:g}"
            v.replay = f"{name}  {pace}  tick {m.tick}/{total}" + (
                "" if rec.raw.complete else "  (partial)")
    finally:
        if screen is not None:
            screen.stop()
    return v, stats
