"""The recorder process (`swarm record`, spawned by `swarm run --record FILE`): every message of
a run into an MCAP file (`swarm.net.record.recording`), from a Zenoh session of its own.

It subscribes to `swarm/<run>/**` before anything else (messages that arrive while it fetches
the run's record from the world are queued, not lost), opens the file, then declares its
liveliness token: the supervisor starts the robots only once that token is up, so the first
tick is recorded. Zenoh's callback only stamps the wall time and queues the payload (bounded;
oversized payloads dropped uncopied, as in `Inbox`); the loop validates, converts and writes.
A payload on a key that is not one of the run's (or names a robot outside the team) is counted,
not written: a flood of made-up keys cannot grow the file's channel table. The recording ends at
the world's `end` record (plus a short grace for the robots' last statuses), when the world's
token has been gone for `GONE_S`, or on SIGINT/SIGTERM; each writes the footer.
"""

from __future__ import annotations

import logging
import queue
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

import zenoh

from swarm.net.inbox import DEFAULT_MAX_BYTES, DEFAULT_MAX_EVENTS, Inbox, query, tally
from swarm.net.keys import WORLD_GONE_S as GONE_S
from swarm.net.keys import Keys
from swarm.net.messages import K_RESULT, K_STATUS, BadMessage, peek_tick, unpack_record
from swarm.net.record.recording import RecordingWriter
from swarm.net.zconfig import ZenohOptions, open_session
from swarm.procs.runconfig import RunRecord

log = logging.getLogger("swarm.recorder")
GRACE_S = 0.3  # after `end`: the robots' final statuses still come
BACKLOG = 50_000  # messages whose JSON form waits for the run's end (~3 s to convert)
HELD = 1_000  # messages held for a tick before the first that names one (then filed at 0)
INTERRUPT_JSON_S = 1.0  # interrupted: JSON forms for this long, then the footer


@dataclass
class RecorderCounters:
    received: int = 0
    oversized: int = 0  # payloads over the size limit, dropped uncopied
    overflow: int = 0  # payloads dropped because the queue was full
    foreign: int = 0  # payloads on keys that are not the run's


class Recorder:
    """Records run `run_id` into `out` until the run ends."""

    def __init__(self, run_id: str, out: str | Path, session: zenoh.Session,
                 wait_world: float = 30.0, flush_s: float = 0.5,
                 wait_said: float | None = None) -> None:
        self.keys = Keys(run_id)
        self.wait_said = wait_said  # (the --wait that `wait_world` is what is left of)
        self.out, self.session = str(out), session
        self.wait_world, self.flush_s = wait_world, flush_s
        self.c = RecorderCounters()
        self.q: queue.Queue[tuple[int, str, bytes]] = queue.Queue(DEFAULT_MAX_EVENTS)
        self.foreign: dict[str, int] = {}
        self.stop = False
        self.result: dict[str, Any] | None = None
        self.tick: int | None = None  # the run tick of the world's last status
        self.ahead = -2  # the run tick of the last status, taken or not
        # what came before any message naming its tick (a recorder that joined late): filed
        # at the first tick named, the run's tick then as well as the recorder can know it
        self.held: list[tuple[str, str, bytes, int]] = []
        self.backlog: list[tuple[str, str, bytes, int, int, int]] = []  # JSON still to write

    def _on_sample(self, s: zenoh.Sample) -> None:
        if len(s.payload) > DEFAULT_MAX_BYTES:
            self.c.oversized += 1
            return
        try:
            self.q.put_nowait((time.time_ns(), str(s.key_expr), s.payload.to_bytes()))
        except queue.Full:
            self.c.overflow += 1

    def _signal(self, signum: int, frame: FrameType | None) -> None:
        self.stop = True  # finish the file from the loop, never halfway through a write

    def run(self) -> dict[str, Any]:
        """Record until the run ends; returns what was counted."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                signal.signal(sig, self._signal)
            except ValueError:  # not the main thread (a test calling main())
                pass
        sub = self.session.declare_subscriber(self.keys.everything, self._on_sample)
        inbox = Inbox(self.session)
        try:
            rec = query(self.session, self.keys.config, self.wait_world,
                        lambda b: RunRecord.unpack(b, f"run record from {self.keys.config}"),
                        f"world answered on {self.keys.config}", lambda: self.stop,
                        self.wait_said)
            w = RecordingWriter(self.out, self.keys.run, rec.to_record(), rec.world,
                                rec.run.clock, rec.run.tick_timeout, flush_s=self.flush_s)
            inbox.liveliness(self.keys.alive_world, "world").token(self.keys.alive_recorder)
            why = "interrupted"
            try:
                why = self._loop(w, rec, inbox)
            finally:  # interrupted (Ctrl-C: SIGKILL follows in 2 s): the footer comes first
                self._drain(w, rec)
                skipped = self._convert(w, None if why != "interrupted" else
                                        time.monotonic() + INTERRUPT_JSON_S)
                c = self.c
                w.finish(self.result, {"ended": why, "received": c.received,
                                       "oversized": c.oversized, "overflow": c.overflow,
                                       "foreign": c.foreign, "json_skipped": skipped})
            return {"ended": why, **vars(c), "messages": w.stats.messages,
                    "bad": sum(w.stats.bad.values())}
        finally:
            sub.undeclare()
            inbox.close()

    def _loop(self, w: RecordingWriter, rec: RunRecord, inbox: Inbox) -> str:
        world_seen, gone_since, end_at = False, None, None
        while not self.stop:
            now = time.monotonic()
            if end_at is not None and now >= end_at:
                return "end"
            if gone_since is not None and now - gone_since >= GONE_S:
                return "world gone"
            while (ev := inbox.next(0.0)) is not None:
                if ev.kind == "world:live":
                    world_seen, gone_since = True, None
                elif ev.kind == "world:dead" and world_seen:
                    gone_since = time.monotonic()
            try:
                item = self.q.get(timeout=0.05)
            except queue.Empty:
                w.maybe_flush()
                continue
            if self._write(w, rec, *item) and end_at is None:
                end_at = time.monotonic() + GRACE_S
        return "interrupted"

    def _drain(self, w: RecordingWriter, rec: RunRecord) -> None:
        while True:
            try:
                item = self.q.get_nowait()
            except queue.Empty:
                break  # (a return left the held messages unwritten, in no counter)
            self._write(w, rec, *item)
        self._release(w, rec, 0)  # (no message named its tick: the run's tick is unknown)

    def _write(self, w: RecordingWriter, rec: RunRecord, wall_ns: int, key: str,
               payload: bytes) -> bool:
        """File one payload at its run tick (held while none is known, see `held`); True when it
        is this run's `end` record."""
        self.c.received += 1
        kind, robot = self.keys.kind_of(key)
        if not kind or (robot is not None and robot >= rec.world.n_robots):
            self.c.foreign += 1
            if tally(self.foreign, key):
                log.warning("not recorded: payload on %s (not a key of run %s)", key,
                            self.keys.run)
            return False
        is_end, head = False, None
        if kind in ("status", "result", "end"):  # records: one a tick at most
            try:
                record = unpack_record(payload, K_STATUS if kind == "status" else K_RESULT)
            except BadMessage:
                record = {}
            head = (record.get("ep"), record.get("t"))
            if kind == "result" and record:
                self.result = record
            is_end = kind == "end" and record.get("run_id") == self.keys.run
        elif kind != "rstatus":
            head = peek_tick(payload)
        tick = run_tick(head, rec, self.tick)
        if tick is None:
            self.held.append((key, kind, payload, wall_ns))
            if len(self.held) >= HELD:
                self._release(w, rec, 0)
            return is_end
        if kind == "status":  # the clock of messages that name no tick (a stale or stray
            # message's own tick does not move it back or ahead; nor does a status that skips
            # ahead, as the supervisor's StatusOrder has it, until the next one follows it)
            if self.tick is None or self.tick <= tick <= self.tick + 1 or tick == self.ahead + 1:
                self.tick = tick
            self.ahead = tick
        self._release(w, rec, tick)
        self._file(w, rec, key, kind, payload, wall_ns, tick)
        return is_end

    def _release(self, w: RecordingWriter, rec: RunRecord, tick: int) -> None:
        """File the held messages at run tick `tick`, in the order they came."""
        for key, kind, payload, wall_ns in self.held:
            self._file(w, rec, key, kind, payload, wall_ns, tick)
        self.held.clear()

    def _file(self, w: RecordingWriter, rec: RunRecord, key: str, kind: str, payload: bytes,
              wall_ns: int, tick: int) -> None:
        """Write one payload raw, at run tick `tick` (its JSON form later, see `_convert`)."""
        vtime = int(round(tick * rec.run.tick_timeout * 1e9))
        w.message(key, kind, payload, None, wall_ns, tick, vtime)
        self.backlog.append((key, kind, payload, wall_ns, tick, vtime))
        if len(self.backlog) >= BACKLOG:
            self._convert(w)

    def _convert(self, w: RecordingWriter, deadline: float | None = None) -> int:
        """The JSON forms of the messages written raw so far (after the run, or when the backlog
        is full: converting while the run goes would take its CPU), until `deadline` (monotonic)
        if given; returns how many were left without one."""
        done = 0
        for key, kind, payload, wall_ns, tick, vtime in self.backlog:
            if self.stop and deadline is None:  # stopped meanwhile (SIGKILL follows in 2 s):
                deadline = time.monotonic() + INTERRUPT_JSON_S  # the footer comes first
            if deadline is not None and time.monotonic() > deadline:
                break
            decoded = w.decode(key, kind, payload)
            if decoded is not None:
                w.json(key, kind, decoded[1], wall_ns, tick, vtime)
            done += 1
        skipped = len(self.backlog) - done
        self.backlog.clear()
        return skipped


def run_tick(head: tuple[Any, Any] | None, rec: RunRecord, last: int | None) -> int | None:
    """The run tick of a message with (episode, tick) `head` (a status: the tick it ends),
    else the last one seen (None: none yet)."""
    ep, t = head or (None, None)
    if isinstance(ep, int) and isinstance(t, int) and 0 <= t <= rec.world.horizon and \
            rec.run.first_episode <= ep < rec.run.first_episode + rec.run.episodes:
        return (ep - rec.run.first_episode) * rec.world.horizon + t
    return last


def main(run_id: str, out: str, zopts: ZenohOptions, wait_world: float = 30.0,
         flush_s: float = 0.5, wait_said: float | None = None) -> dict[str, Any]:
    """Open a session and record run `run_id` into `out`."""
    with open_session(zopts, wait_world) as session:
        return Recorder(run_id, out, session, wait_world, flush_s, wait_said).run()
