"""A run's traffic as an MCAP file: what `swarm record` writes and `swarm replay|trace` read.

Layout of a recording (format FORMAT):
- metadata `swarm.recording`: format, message schema version, run id, clock, tick length, start;
- attachment `run_record.json`: the run's `RunRecord` (world, run, faults, ...) at its start;
  `result.json`: the world's result record (absent when the recorder was stopped first);
  metadata `swarm.recorder`: what the recorder counted (messages, bad, dropped);
- per Zenoh key two channels: topic = the key, message encoding `msgpack`, no schema: the
  payload bit-exact as it was on the wire; topic = key + `/json`, encoding `json` with a
  `jsonschema` schema per message kind (`swarm.net.record.msgjson`): the validated, decoded message;
- every message: log time = wall clock at receipt (ns since the epoch), publish time = the
  run's virtual time at its tick (ns), sequence = the run tick: its own for the kinds of
  `TICKED`, the last one the recorder saw for the others (before any, as in a recorder that
  joined a run late: the first tick a message names after them, so no message lies before
  the span; `RawRecording.span` gives the ticks a recording holds).

Chunks are small and flushed every `flush_s`, so a SIGKILLed recorder leaves every chunk
flushed before it readable (`read(..., partial=True)`). The reader treats the file as hostile:
wrong magic, records or chunks over the size limit, bad CRCs, another format or schema version
and a cut-off end are one-line `RecordingError`s (a `ConfigError`: exit status 2 in the CLI).
"""

from __future__ import annotations

import datetime as dt
import json
import os
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from swarm.net.keys import Keys
from swarm.net.messages import SCHEMA, BadMessage
from swarm.net.record import msgjson
from world.config import ConfigError, WorldConfig

FORMAT = 1
PROFILE = "commattn-swarm"
META, STATS = "swarm.recording", "swarm.recorder"
RUN_RECORD, RESULT = "run_record.json", "result.json"
JSON_SUFFIX = "/json"
LIMIT = 256 << 20  # largest record or decompressed chunk a reader accepts
MAGIC = b"\x89MCAP0\r\n"
TICKED = frozenset({"obs", "traj", "bundle", "hidden", "radio_hidden", "action", "status"})
"""Kinds whose payload names its own (episode, tick), so their sequence is their run tick."""


class RecordingError(ConfigError):
    """A file that is not a readable recording of this build (one line, exit status 2)."""


def need_mcap() -> Any:
    """The `mcap` package, or a one-line error naming the extra that installs it."""
    try:
        import mcap.writer

        return mcap
    except ImportError:
        raise ConfigError("recordings need the mcap package: pip install "
                          "'commattn-swarm[record]'") from None


@dataclass
class WriterStats:
    messages: int = 0  # raw messages written
    json: int = 0  # of which also written as JSON
    bad: dict[str, int] = field(default_factory=dict)  # per key: no JSON form (failed checks)
    bytes: int = 0


def json_form(kind: str, payload: bytes, cfg: WorldConfig) -> tuple[dict[str, Any], bytes] | None:
    """The payload's validated JSON form (`msgjson.to_json`) and its encoding as a recording
    holds it, or None when it has none (a payload every process would drop)."""
    try:
        obj = msgjson.to_json(kind, payload, cfg)
        return obj, json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()
    except (BadMessage, ValueError, TypeError, KeyError, OverflowError, RecursionError):
        return None


class RecordingWriter:
    """Writes one run's recording; `message` per payload, `finish` at the end."""

    def __init__(self, path: str | Path, run_id: str, record: dict[str, Any], cfg: WorldConfig,
                 clock: str, tick_s: float, chunk_bytes: int = 64 << 10,
                 flush_s: float = 0.5) -> None:
        mcap = need_mcap()
        from mcap.writer import CompressionType, Writer

        self.cfg, self.flush_s = cfg, flush_s
        self.fh: IO[bytes] = open(path, "wb")  # noqa: SIM115 (closed in finish)
        self.w = Writer(self.fh, chunk_size=chunk_bytes, compression=CompressionType.ZSTD)
        self.w.start(profile=PROFILE, library=f"commattn-swarm (mcap {mcap.__version__})")
        self.w.add_metadata(META, {
            "format": str(FORMAT), "schema": str(SCHEMA), "run_id": run_id, "clock": clock,
            "tick_s": repr(float(tick_s)), "started": dt.datetime.now(dt.UTC).isoformat()})
        self.attach(RUN_RECORD, record)
        self.stats = WriterStats()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, int]] = {}
        self._last_flush = time.monotonic()
        self.w.flush()

    def attach(self, name: str, obj: Any) -> None:
        now = time.time_ns()
        data = json.dumps(msgjson.safe(obj), allow_nan=False).encode()
        self.w.add_attachment(now, now, name, "application/json", data)

    def _channel(self, key: str, kind: str) -> tuple[int, int]:
        ids = self._channels.get(key)
        if ids is None:
            sid = self._schemas.get(kind)
            if sid is None:
                sid = self._schemas[kind] = self.w.register_schema(
                    f"swarm.{kind}", "jsonschema",
                    json.dumps(msgjson.SCHEMAS.get(kind, msgjson.GENERIC)).encode())
            meta = {"kind": kind, "key": key}
            ids = self._channels[key] = (
                self.w.register_channel(key, "msgpack", 0, {**meta, "form": "raw"}),
                self.w.register_channel(key + JSON_SUFFIX, "json", sid, {**meta, "form": "json"}))
        return ids

    def decode(self, key: str, kind: str, payload: bytes) -> tuple[dict[str, Any], bytes] | None:
        """The payload's `json_form`, or None (counted in `stats.bad` under its key)."""
        form = json_form(kind, payload, self.cfg)
        if form is None:
            self.stats.bad[key] = self.stats.bad.get(key, 0) + 1
        return form

    def message(self, key: str, kind: str, payload: bytes, data: bytes | None,
                wall_ns: int, tick: int, vtime_ns: int) -> None:
        """One payload received on `key` (of `kind`, see Keys.kind_of): raw always, and its
        JSON form `data` (from `decode`) when it has one."""
        raw, js = self._channel(key, kind)
        seq = max(0, min(tick, 2**32 - 1))
        self.w.add_message(raw, log_time=wall_ns, data=payload, publish_time=vtime_ns,
                           sequence=seq)
        self.stats.messages += 1
        self.stats.bytes += len(payload)
        if data is not None:
            self.w.add_message(js, log_time=wall_ns, data=data, publish_time=vtime_ns,
                               sequence=seq)
            self.stats.json += 1
        self.maybe_flush()

    def json(self, key: str, kind: str, data: bytes, wall_ns: int, tick: int,
             vtime_ns: int) -> None:
        """The JSON form (from `decode`) of a payload already written raw."""
        js = self._channel(key, kind)[1]
        self.w.add_message(js, log_time=wall_ns, data=data, publish_time=vtime_ns,
                           sequence=max(0, min(tick, 2**32 - 1)))
        self.stats.json += 1
        self.maybe_flush()

    def maybe_flush(self) -> None:
        """Finish the chunk and flush the file every `flush_s` (what a SIGKILL leaves)."""
        if time.monotonic() - self._last_flush >= self.flush_s:
            self.w.flush()
            self._last_flush = time.monotonic()

    def finish(self, result: dict[str, Any] | None, extra: dict[str, Any]) -> None:
        """Result attachment, the recorder's counts, summary and footer; closes the file."""
        if result is not None:
            try:  # the result came from the wire: whatever it holds, the footer gets written
                self.attach(RESULT, result)
            except (BadMessage, ValueError, TypeError, RecursionError, OverflowError):
                extra = {**extra, "result": "unreadable"}
        s = self.stats
        self.w.add_metadata(STATS, {k: str(v) for k, v in {
            "messages": s.messages, "json": s.json, "bad": sum(s.bad.values()),
            "bytes": s.bytes, "finished": dt.datetime.now(dt.UTC).isoformat(),
            **extra}.items()})
        self.w.finish()
        self.fh.flush()
        os.fsync(self.fh.fileno())  # (the footer on disk before the recorder says it is done)
        self.fh.close()


@dataclass
class RawMessage:
    """A raw payload of the recording: receipt wall time and virtual time (ns), run tick, key."""

    wall_ns: int
    vtime_ns: int
    tick: int
    key: str
    payload: bytes


@dataclass
class RawRecording:
    """What a file holds, checked against the format but not yet against a run."""

    path: str
    meta: dict[str, str]
    attachments: dict[str, bytes]
    stats: dict[str, str]
    keys: list[str]  # topics of the raw channels
    json_topics: list[str]
    messages: list[RawMessage]
    complete: bool  # the footer was read: the recorder finished
    end_offset: int  # bytes read before the end (or the cut)
    damaged: bool = False  # not complete, and not for want of the rest: see `read`
    size: int = 0  # of the file, in bytes
    json_messages: list[RawMessage] = field(default_factory=list)  # key: its raw channel's
    bad_from: int = 0  # where the record that failed starts (a damaged chunk: its first byte)

    def where_bad(self) -> str:
        """The bytes of the record that failed, as a reader can find them: a chunk's CRC names
        the chunk, not the byte in it."""
        return f"bytes {self.bad_from}-{self.end_offset} of {self.size}"

    def attachment(self, name: str) -> Any:
        """A JSON attachment, or None when absent; RecordingError when it does not parse."""
        data = self.attachments.get(name)
        if data is None:
            return None
        try:
            return json.loads(data)
        except ValueError:
            raise RecordingError(f"{self.path}: attachment {name} is not JSON") from None

    def span(self) -> tuple[int, int] | None:
        """(first, last) run tick of the messages that name their own (kinds `TICKED`), or None
        when none does. A recorder started after the run began holds no tick 0."""
        keys, kinds = Keys(self.meta.get("run_id", "")), {}
        ticks = [m.tick for m in self.messages
                 if kinds.setdefault(m.key, keys.kind_of(m.key)[0]) in TICKED]
        return (min(ticks), max(ticks)) if ticks else None


def read(path: str | Path, partial: bool = False) -> RawRecording:
    """Every raw message of a recording, in file (= arrival) order. A file that ends before its
    footer is a RecordingError unless `partial` (then: every complete chunk before the cut).
    Such a file is `damaged` rather than cut short when the recorder finished it (it ends in
    the closing magic), or a record in it is wrong (a bad CRC, length or encoding, not one
    that runs past the end), or it fails more than 4 KiB before its end."""
    need_mcap()
    from mcap.exceptions import EndOfFile
    from mcap.records import Attachment, Channel, Chunk, Footer, Message, Metadata
    from mcap.stream_reader import StreamReader, breakup_chunk

    path = str(path)
    try:
        fh = open(path, "rb")  # noqa: SIM115
    except OSError as exc:
        raise RecordingError(f"cannot read {path}: {exc.strerror or exc}") from None
    meta: dict[str, str] = {}
    stats: dict[str, str] = {}
    attachments: dict[str, bytes] = {}
    channels: dict[int, Any] = {}
    messages: list[RawMessage] = []
    forms: list[RawMessage] = []
    complete, error, short = False, "", False
    with fh:
        if fh.read(len(MAGIC)) != MAGIC:
            raise RecordingError(f"{path} is not an MCAP file")
        fh.seek(0)
        reader = StreamReader(fh, emit_chunks=True, validate_crcs=True, record_size_limit=LIMIT)

        def take(rec: Any) -> None:
            if isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Message):
                ch = channels.get(rec.channel_id)
                if ch is None:
                    raise RecordingError(f"{path}: a message on unknown channel {rec.channel_id}")
                if ch.message_encoding == "msgpack":
                    messages.append(RawMessage(rec.log_time, rec.publish_time, rec.sequence,
                                               ch.topic, bytes(rec.data)))
                elif ch.topic.endswith(JSON_SUFFIX):
                    forms.append(RawMessage(rec.log_time, rec.publish_time, rec.sequence,
                                            ch.topic[:-len(JSON_SUFFIX)], bytes(rec.data)))

        good = fh.tell()  # (the end of the last record read whole: where a failed one starts)
        try:
            for rec in reader.records:
                if isinstance(rec, Chunk):
                    if rec.uncompressed_size > LIMIT:
                        raise RecordingError(f"{path}: a chunk of {rec.uncompressed_size} bytes")
                    for inner in breakup_chunk(rec, validate_crc=True):
                        take(inner)
                elif isinstance(rec, Metadata):
                    if rec.name == META and not meta:
                        meta = dict(rec.metadata)
                    elif rec.name == STATS:
                        stats = dict(rec.metadata)
                elif isinstance(rec, Attachment):
                    attachments.setdefault(rec.name, bytes(rec.data))
                elif isinstance(rec, Footer):
                    complete = True
                else:
                    take(rec)
                good = fh.tell()
        except RecordingError:
            raise
        except Exception as exc:  # anything a cut or corrupt file raises inside the reader
            error = f"{type(exc).__name__}: {exc}"[:200]
            short = isinstance(exc, EndOfFile | struct.error)  # the file ran out mid-record
        end = fh.tell()
        fh.seek(-len(MAGIC), 2)  # (the opening magic was read: the file is that long)
        closed = fh.read(len(MAGIC)) == MAGIC  # the recorder finished the file
        if complete and not closed:  # a footer, and no closing magic: a file cut in it
            complete, error, short = False, "no closing magic", True
    if not meta:
        raise RecordingError(f"{path} is not a swarm recording (no {META} metadata"
                             + (f"; unreadable at byte {end}: {error})" if error else ")"))
    if meta.get("format") != str(FORMAT):
        raise RecordingError(f"{path} is in recording format {meta.get('format')!r}; this "
                             f"build reads format {FORMAT}")
    if meta.get("schema") != str(SCHEMA):
        raise RecordingError(f"{path} holds messages of schema version {meta.get('schema')!r}; "
                             f"this build reads version {SCHEMA}")
    size = Path(path).stat().st_size
    damaged = bool(error) and (closed or not short or end < size - 4096)
    if not complete and not partial:
        last = max((m.tick for m in messages), default=0)
        if damaged:
            raise RecordingError(f"{path} is damaged or cut: unreadable at bytes {good}-{end} "
                                 f"of {size} "
                                 f"({len(messages)} messages readable up to run tick {last}); "
                                 "--partial uses what is there")
        why = f"unreadable at bytes {good}-{end}" if error else "no footer"
        raise RecordingError(f"{path} is truncated ({why}: the recorder stopped before the end; "
                             f"{len(messages)} messages readable up to run tick {last}); "
                             "--partial uses what is there")
    topics = [c.topic for c in channels.values()]
    return RawRecording(path, meta, attachments, stats,
                        [c.topic for c in channels.values() if c.message_encoding == "msgpack"],
                        [t for t in topics if t.endswith(JSON_SUFFIX)], messages, complete, end,
                        damaged, size, forms, good if error else end)


def check_json_forms(raw: RawRecording, cfg: WorldConfig
                     ) -> tuple[int, tuple[str, int, tuple[Any, Any], Any, Any] | None]:
    """Every JSON form of `raw` against the raw payload it stands beside: (forms checked, the
    first that differs as (what, run tick, its (episode, tick) or Nones, recorded, expected), or
    None). Per key the forms are the `json_form`s of its raw payloads that have one, in order,
    with their times and sequence. A file its recorder finished holds one for each, but for the
    last `json_skipped` raw messages (an interrupted recorder's deadline); one cut short may
    lack any (they are written after the run), never hold one with no raw payload."""
    keys = Keys(raw.meta.get("run_id", ""))
    expected: dict[str, list[tuple[int, RawMessage, Any]]] = {}
    at: dict[tuple[str, int, int, int], list[int]] = {}  # (key, times) -> places in expected
    for idx, msg in enumerate(raw.messages):
        form = json_form(keys.kind_of(msg.key)[0] or "", msg.payload, cfg)
        if form is not None:  # (as a JSON reader reads it back: tuples are lists)
            forms = expected.setdefault(msg.key, [])
            at.setdefault((msg.key, msg.tick, msg.vtime_ns, msg.wall_ns), []).append(len(forms))
            forms.append((idx, msg, json.loads(form[1])))
    used: dict[str, set[int]] = {}
    for n, js in enumerate(raw.json_messages):
        topic, beside = js.key + JSON_SUFFIX, " (the JSON form of the raw payload beside it)"
        taken = used.setdefault(js.key, set())
        # paired by times (a deleted form is then one missing, not the next one's change)
        same = [k for k in at.get((js.key, js.tick, js.vtime_ns, js.wall_ns), ())
                if k not in taken]
        k = same[0] if same else next(
            (k for k in range(len(expected.get(js.key, []))) if k not in taken), None)
        if k is None:
            return n, (f"{topic} (a JSON form with no raw payload beside it)", js.tick,
                       (None, None), js.payload.decode("utf-8", "replace"), None)
        taken.add(k)
        _, msg, want = expected[js.key][k]
        head = (want.get("ep"), want.get("t"))
        try:
            got = json.loads(js.payload)
        except ValueError:
            got = js.payload.decode("utf-8", "replace")
        if got != want:
            field = next((f for f in want if got.get(f, ...) != want[f]), None) \
                if isinstance(got, dict) else None
            if field is None:
                return n, (topic + beside, msg.tick, head, got, want)
            return n, (f"{topic} {field}{beside}", msg.tick, head, got[field], want[field])
        times = (js.tick, js.vtime_ns, js.wall_ns), (msg.tick, msg.vtime_ns, msg.wall_ns)
        if times[0] != times[1]:
            return n, (f"{topic} (sequence, publish and log time){beside}", msg.tick, head,
                       *times)
    if raw.complete:
        try:
            last = len(raw.messages) - int(raw.stats.get("json_skipped", 0))
        except ValueError:
            last = len(raw.messages)
        missing = [(idx, key, msg, want) for key, forms in expected.items()
                   for k, (idx, msg, want) in enumerate(forms)
                   if k not in used.get(key, ()) and idx < last]
        if missing:
            _, key, msg, want = min(missing, key=lambda m: m[0])
            return len(raw.json_messages), (
                f"{key}{JSON_SUFFIX} (no JSON form of the raw payload beside it)", msg.tick,
                (want.get("ep"), want.get("t")), None, want)
    return len(raw.json_messages), None
