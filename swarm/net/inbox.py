"""The one way a process listens: every subscription, liveliness change and query of a process
lands as an `Event` in one queue, read by the process's own loop (never handled in Zenoh's
callback threads), and every entity is undeclared when the inbox closes.

Hostile input is cut here before it costs anything: a payload over `max_bytes` is dropped
and counted without being copied out of Zenoh, and a full queue drops (and counts) the newest
event instead of growing without bound under a flood.
"""

from __future__ import annotations

import heapq
import logging
import queue
import time
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple, TypeVar

import zenoh

log = logging.getLogger("swarm.inbox")
T = TypeVar("T")

DEFAULT_MAX_BYTES = 4 << 20  # far above any message of a run (weights of the largest net: ~1 MB)
DEFAULT_MAX_EVENTS = 100_000
WAIT_SLICE_S = 0.25
"""The longest a process's main thread sleeps in one piece while waiting for an event. A signal
(SIGTERM from a supervisor's death, Ctrl-C) may be taken by any thread of the process, most often
one of Zenoh's; its Python handler then runs only when the main thread next wakes. One long
wait made a world outlive its supervisor for the whole robot start-up timeout."""
LAST_PUT_S = 0.05
"""What a process that leaves gives its last puts to go out before its session closes: Zenoh
batches them, and a close drops what is still queued (without it, 12-61 of 200 robots' final
statuses never reached their supervisor, on two cores)."""


class Event(NamedTuple):
    """What arrived: `kind` names the subscription (`<kind>:live`/`<kind>:dead` for liveliness)."""

    kind: str
    key: str
    payload: bytes | None


class Inbox:
    """A process's subscriptions into one bounded queue; use as a context manager."""

    def __init__(self, session: zenoh.Session, max_bytes: int = DEFAULT_MAX_BYTES,
                 max_events: int = DEFAULT_MAX_EVENTS) -> None:
        self.session = session
        self.max_bytes = max_bytes
        # SimpleQueue (C) rather than Queue (Python, a Condition per call): every message of a
        # process passes here, ~300 a tick in a 100-robot world; the bound is kept by hand
        self.q: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self.max_events = max_events
        self.oversized = 0  # payloads over max_bytes, dropped uncopied
        self.overflow = 0  # events dropped because the queue was full
        self._ents: list[Any] = []

    @property
    def dropped(self) -> dict[str, int]:
        """What this inbox dropped before any reader saw it: payloads over `max_bytes`
        (`oversized`) and events past the queue's bound (`overflow`); every process reports
        them beside its own counters."""
        return {"oversized": self.oversized, "overflow": self.overflow}

    def _offer(self, event: Event) -> None:
        if self.q.qsize() >= self.max_events:  # (callbacks race here: the bound is +-threads)
            self.overflow += 1
        else:
            self.q.put(event)

    def subscribe(self, key: str, kind: str, remote: bool = False) -> Inbox:
        """Samples on `key` arrive as Event(kind, sample key, payload bytes); with `remote`,
        only those other sessions put (not this process's own)."""
        def on_sample(s: zenoh.Sample) -> None:
            if len(s.payload) > self.max_bytes:
                self.oversized += 1
                return
            self._offer(Event(kind, str(s.key_expr), s.payload.to_bytes()))

        origin = zenoh.Locality.REMOTE if remote else None
        self._ents.append(self.session.declare_subscriber(key, on_sample, allowed_origin=origin))
        return self

    def liveliness(self, key: str, kind: str, history: bool = True) -> Inbox:
        """Liveliness tokens matching `key` arrive as Event(kind + ':live' or ':dead', key)."""
        def on_change(s: zenoh.Sample) -> None:
            state = "live" if s.kind == zenoh.SampleKind.PUT else "dead"
            self._offer(Event(f"{kind}:{state}", str(s.key_expr), None))

        self._ents.append(self.session.liveliness().declare_subscriber(key, on_change,
                                                                       history=history))
        return self

    def token(self, key: str) -> Inbox:
        """Declare this process alive on `key` until the inbox closes."""
        self._ents.append(self.session.liveliness().declare_token(key))
        return self

    def queryable(self, key: str, reply: Callable[[], bytes]) -> Inbox:
        """Answer queries on `key` with `reply()` (called in Zenoh's thread: keep it a lookup)."""
        self._ents.append(self.session.declare_queryable(
            key, lambda query: query.reply(key, reply())))
        return self

    def next(self, timeout: float) -> Event | None:
        """The next event within `timeout` seconds (any finite or infinite value), else None."""
        if not timeout > 0:  # also NaN
            timeout = 0.0
        end = time.monotonic() + min(timeout, 3600.0)
        while True:
            try:
                return self.q.get(timeout=max(0.0, min(end - time.monotonic(), WAIT_SLICE_S)))
            except queue.Empty:
                if time.monotonic() >= end:
                    return None

    def close(self) -> None:
        for ent in reversed(self._ents):
            try:
                ent.undeclare()
            except Exception:  # a session already closed has undeclared them
                pass
        self._ents.clear()

    def __enter__(self) -> Inbox:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def replies(session: zenoh.Session, key: str, timeout: float) -> Iterator[bytes]:
    """Every reply's payload to one query on `key`, with no consolidation: Zenoh's default
    keeps one reply per key (the latest), so a foreign peer's queryable on the same key could
    hide the real answer behind its own. The caller checks each one."""
    for reply in session.get(key, timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is not None:
            yield reply.ok.payload.to_bytes()


def query(session: zenoh.Session, key: str, timeout: float, parse: Callable[[bytes], T],
          what: str = "", stop: Callable[[], bool] = lambda: False,
          said: float | None = None) -> T:
    """`parse` of the first reply on `key` that it takes, retried until `timeout` seconds. A
    reply `parse` refuses (a ValueError: BadMessage, ConfigError) is hostile input: dropped,
    counted and logged, and the next one is tried, so a foreign peer answering with garbage
    cannot stop a process from joining its run. A one-line TimeoutError naming `what` (default:
    the key) and the replies dropped when no good one came, and KeyboardInterrupt once `stop()`
    (a signal handler's flag) is true. `said`: the wait the error names, when `timeout` is
    what is left of a wait the user gave (`--wait 0.5` said "within 0.49 s")."""
    deadline = time.monotonic() + timeout
    dropped, last = 0, ""
    while True:
        if stop():
            raise KeyboardInterrupt
        left = deadline - time.monotonic()
        for payload in replies(session, key, max(0.05, min(1.0, left))):
            try:
                return parse(payload)
            except ValueError as exc:
                dropped, last = dropped + 1, str(exc)
                if dropped & (dropped - 1) == 0:  # the 1st, 2nd, 4th...: no flood fills the log
                    log.warning("dropped an unreadable reply on %s (%d so far): %s", key,
                                dropped, last)
        if time.monotonic() >= deadline:
            why = f" ({dropped} unreadable replies dropped; the last: {last})" if dropped else ""
            named = round(said or timeout, 2)  # (a budget's remainder: 1.99932 s is 2 s)
            raise TimeoutError(f"no {what or 'answer on ' + key} within {named:g} s{why}")
        time.sleep(0.1)


def tally(counts: dict[str, int], key: str, cap: int = 64) -> bool:
    """Count one dropped payload under its key; past `cap` distinct keys (a flood of made-up
    keys) the rest share one entry, so the table cannot grow without bound. True when this one
    is worth a log line (the first few of a key, then every power of two: a flood cannot fill
    the log)."""
    if key not in counts and len(counts) >= cap:
        key = "(other keys)"
    n = counts[key] = counts.get(key, 0) + 1
    return n <= 3 or n & (n - 1) == 0


def publisher(session: zenoh.Session, key: str, express: bool = False) -> zenoh.Publisher:
    """The run's publishers: congestion control BLOCK, never Zenoh's default DROP, which drops a
    message silently when the receiver's link stays congested past 1 ms (a busy 2-core machine
    does that: a lost status or action would be a silent loss). `express` sends at once,
    unbatched (the hidden-state chain: each hop waits for the message)."""
    return session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                     express=express)


def put_once(session: zenoh.Session, key: str, payload: bytes) -> None:
    """One put without a publisher (a control record), with `publisher`'s congestion control:
    `Session.put` defaults to DROP, which would lose a stop or a fault change silently on a
    congested link."""
    session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)


class Outbox:
    """Payloads put at later wall-clock (monotonic) times, in order of time, then of scheduling:
    the real clock's radio latency. `put(key, payload)` is the process's publisher."""

    def __init__(self, put: Callable[[str, bytes], None]) -> None:
        self._put = put
        self._due: list[tuple[float, int, str, bytes]] = []
        self._seq = 0

    def schedule(self, when: float, key: str, payload: bytes) -> None:
        if when <= time.monotonic():
            self._put(key, payload)
        else:
            self._seq += 1
            heapq.heappush(self._due, (when, self._seq, key, payload))

    def flush(self) -> None:
        """Put every payload whose time has come."""
        now = time.monotonic()
        while self._due and self._due[0][0] <= now:
            _, _, key, payload = heapq.heappop(self._due)
            self._put(key, payload)

    def until(self, deadline: float) -> float:
        """The earlier of `deadline` and the next payload's time."""
        return min(deadline, self._due[0][0]) if self._due else deadline

    def clear(self) -> None:
        self._due.clear()


def check_free(session: zenoh.Session, key: str, what: str, timeout: float = 2.0,
               since: float | None = None, settle: float = 0.0) -> None:
    """A process taking an id: ConfigError (one line) if a liveliness token on `key` is up
    anywhere this session reaches (`what`, say "robot 3 of run R", is running already).

    A peer reaches another peer only once gossip has linked them, which under load may come
    after the first query: the query is asked again until `settle` s have passed since `since`
    (the session's opening, monotonic clock) and the session's peers stayed the same for a
    quarter of it (at most 3 x `settle` in all: a swarm whose peers keep coming and going)."""
    from world.config import ConfigError

    def peers() -> set[str]:
        return {str(z) for z in (*session.info.peers_zid(), *session.info.routers_zid())}

    start = time.monotonic() if since is None else since
    seen, changed = peers(), time.monotonic()
    while True:
        if any(r.ok is not None for r in session.liveliness().get(key, timeout=timeout)):
            raise ConfigError(f"{what} is running already (its liveliness token is up)")
        now, linked = time.monotonic(), peers()
        if linked != seen:
            seen, changed = linked, now
        if now - start >= settle and (now - changed >= settle / 4 or now - start >= 3 * settle):
            return
        time.sleep(0.1)
