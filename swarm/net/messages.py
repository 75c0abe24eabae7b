"""The msgpack schemas of every message of a run (the learning ones in swarm.net.learning);
nothing else knows a payload's fields: readers that need only a message's tick ask `peek_tick`,
and a control record's contents are checked by `swarm.net.faults.control.check_control`.

Each payload is a msgpack array `[SCHEMA, kind, ...fields]`. `unpack` validates types, ranges
and sizes against the run's world config and raises `BadMessage` (a one-line reason); the
callers drop and count such payloads, they never crash. Trajectory messages are compact: the
visited bitmap is bit-packed (H*W/8 bytes) and the patch is v*v bytes: at most 112 bytes in all
on the default 20 x 20 map (102 on average).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

from world.config import WorldConfig

SCHEMA = 1
(K_OBS, K_TRAJ, K_BUNDLE, K_HIDDEN, K_ACTION, K_STATUS, K_RSTATUS, K_RESULT, K_CONTROL,
 K_WEIGHTS, K_RROLLOUT, K_EPISODE, K_EROLLOUT, K_LSTATUS) = range(14)
BIG = 2**31 - 1
MAX_MS = 3.6e6  # an hour: the longest duration any message may carry
MAX_TOKENS = 1e15  # bytes a token bucket may hold or owe
MAX_FAULTS_BYTES = 65536  # a live fault table carried in an observation (direct delivery)


class BadMessage(ValueError):
    """A payload that does not decode or does not fit its schema."""


def _pack(kind: int, *fields: Any) -> bytes:
    return msgpack.packb([SCHEMA, kind, *fields], use_bin_type=True)


def _unpack(payload: bytes, kind: int, n_fields: int | tuple[int, ...]) -> list[Any]:
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several types; all mean "not msgpack"
        raise BadMessage(f"not msgpack ({type(exc).__name__})") from None
    if not isinstance(obj, list) or len(obj) < 2:
        raise BadMessage("not a schema array")
    if type(obj[0]) is not int or obj[0] != SCHEMA:  # (1.0 and True equal 1)
        raise BadMessage(f"schema version {obj[0]!r}, expected {SCHEMA}")
    if type(obj[1]) is not int or obj[1] != kind:
        raise BadMessage(f"message kind {obj[1]!r}, expected {kind}")
    if len(obj) - 2 not in ((n_fields,) if isinstance(n_fields, int) else n_fields):
        raise BadMessage(f"{len(obj) - 2} fields, expected {n_fields}")
    return obj[2:]


def _int(v: Any, name: str, lo: int, hi: int) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise BadMessage(f"{name}={v!r} not an integer in [{lo}, {hi}]")
    return v


def _ints(values: list[Any], name: str, lo: int, hi: int) -> list[int]:
    """`_int` of every element, with one pass of builtins for the common all-good case."""
    if values and not (all(type(v) is int for v in values) and lo <= min(values)
                       and max(values) <= hi):
        for v in values:
            _int(v, name, lo, hi)
    return values


def _float(v: Any, name: str, lo: float = -1e9, hi: float = 1e9) -> float:
    """A finite number in [lo, hi] (every float on the wire has a range, not just a type)."""
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not lo <= v <= hi:
        raise BadMessage(f"{name}={v!r} not a number in [{lo:g}, {hi:g}]")
    return float(v)


def _bytes(v: Any, name: str, size: int) -> bytes:
    if not isinstance(v, bytes) or len(v) != size:
        raise BadMessage(f"{name} must be {size} bytes")
    return v


def _bucket(v: Any) -> tuple[float, float] | None:
    """A token bucket on the wire: None (absent) or [tokens, ms of its last charge], each in
    range (tokens may be negative: bytes owed by a queue)."""
    if v is None or v == []:
        return None
    if not isinstance(v, list) or len(v) != 2:
        raise BadMessage("bucket must be [tokens, last_ms]")
    return (_float(v[0], "bucket tokens", -MAX_TOKENS, MAX_TOKENS),
            _float(v[1], "bucket last_ms", 0.0, MAX_TOKENS))


@dataclass
class Obs:
    """World -> robot `robot`: its observation at tick `t` of episode `ep`."""

    ep: int
    t: int
    robot: int
    y: int
    x: int
    patch: bytes  # v*v codes, see world.core.patches
    reward: float  # reward of the previous step (0 at t = 0)
    done: bool  # the episode has ended: no action is expected for this tick
    budget_ms: float  # time left until the world's action deadline when it sent this
    live: bytes = b""  # direct delivery: np.packbits of the robots the world sent this tick to
    # (whose trajectory messages a robot waits for); empty (and not sent) with the radio
    faults: bytes = b""  # direct delivery: the run's `[faults]` table (msgpack) from this tick
    # on, after a live change (`swarm fault`); empty when the plan did not change
    bucket: tuple[float, float] | None = None  # direct delivery under a bandwidth cap: the
    # robot's own token bucket (tokens, ms of its last charge) after its last action this
    # episode, as its action reported it; a restarted robot takes it up (`Action.bucket`)
    version: int | None = None  # lockstep field training (`RunConfig.train_sync`), tick 0: the
    # learner's weights version every robot must act with this episode; None (not sent) else

    def pack(self) -> bytes:
        tail: list[Any] = [self.live, self.faults, list(self.bucket or ())]
        if self.version is not None:
            tail.append(self.version)
        while tail and not tail[-1] and len(tail) < 4:  # empty trailing fields are not sent
            tail.pop()
        return _pack(K_OBS, self.ep, self.t, self.robot, self.y, self.x, self.patch, self.reward,
                     self.done, self.budget_ms, *tail)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> Obs:
        ep, t, robot, y, x, patch, reward, done, budget, *rest = _unpack(payload, K_OBS,
                                                                        (9, 10, 11, 12, 13))
        if not isinstance(done, bool):
            raise BadMessage("done must be a bool")
        live = b"" if not rest or rest[0] == b"" else _bytes(rest[0], "live",
                                                             (cfg.n_robots + 7) // 8)
        faults = rest[1] if len(rest) > 1 else b""
        if not isinstance(faults, bytes) or len(faults) > MAX_FAULTS_BYTES:
            raise BadMessage(f"faults must be at most {MAX_FAULTS_BYTES} bytes")
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon),
                   _int(robot, "robot", 0, cfg.n_robots - 1), _int(y, "y", 0, cfg.height - 1),
                   _int(x, "x", 0, cfg.width - 1), _bytes(patch, "patch", cfg.vision ** 2),
                   _float(reward, "reward"), done, _float(budget, "budget_ms", 0.0, MAX_MS),
                   live, faults, _bucket(rest[2] if len(rest) > 2 else None),
                   None if len(rest) < 4 or rest[3] is None else _int(rest[3], "version", 0, BIG))


@dataclass
class Traj:
    """Robot -> radio: the trajectory message of SPEC section 3 (all a receiver's encoder needs)."""

    ep: int
    t: int
    robot: int
    y: int
    x: int
    visited: bytes  # np.packbits of the sender's own H*W visited bitmap
    recent: list[int]  # last positions y*W+x, oldest first, at most recent_len
    patch: bytes

    def pack(self) -> bytes:
        return _pack(K_TRAJ, self.ep, self.t, self.robot, self.y, self.x, self.visited,
                     self.recent, self.patch)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> Traj:
        ep, t, robot, y, x, visited, recent, patch = _unpack(payload, K_TRAJ, 8)
        if not isinstance(recent, list) or len(recent) > cfg.recent_len:
            raise BadMessage(f"recent must be a list of at most {cfg.recent_len} cells")
        recent = _ints(recent, "recent cell", 0, cfg.cells - 1)
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon),
                   _int(robot, "robot", 0, cfg.n_robots - 1), _int(y, "y", 0, cfg.height - 1),
                   _int(x, "x", 0, cfg.width - 1), _bytes(visited, "visited", (cfg.cells + 7) // 8),
                   recent, _bytes(patch, "patch", cfg.vision ** 2))

    def visited_bits(self, cells: int) -> np.ndarray:
        return np.unpackbits(np.frombuffer(self.visited, dtype=np.uint8), count=cells).astype(bool)

    @classmethod
    def unpack_many(cls, payloads: list[bytes], cfg: WorldConfig, ep: int, t: int) -> list[Traj]:
        """The messages of one bundle (tick (ep, t), distinct senders), every field checked as
        `unpack` checks it, but column by column: a bundle holds tens of messages and one check
        per column costs what one message's checks cost. BadMessage names the first bad one."""
        try:
            rows = [_unpack(p, K_TRAJ, 8) for p in payloads]
            columns = zip(*rows, strict=True) if rows else [()] * 8
            eps, ts, robots, ys, xs, visited, recents, patches = columns
            ints = [*eps, *ts, *robots, *ys, *xs]
            vbytes, pbytes = (cfg.cells + 7) // 8, cfg.vision ** 2
            ok = (all(type(v) is int for v in ints)
                  and all(v == ep for v in eps) and all(v == t for v in ts)
                  and len(set(robots)) == len(robots)
                  and all(0 <= v < cfg.n_robots for v in robots)
                  and all(0 <= v < cfg.height for v in ys) and all(0 <= v < cfg.width for v in xs)
                  and all(type(v) is bytes and len(v) == vbytes for v in visited)
                  and all(type(v) is bytes and len(v) == pbytes for v in patches)
                  and all(type(v) is list and len(v) <= cfg.recent_len for v in recents))
            cells = [c for r in recents for c in r] if ok else []
            ok = ok and all(type(c) is int for c in cells) and (
                not cells or (0 <= min(cells) and max(cells) < cfg.cells))
        except BadMessage:
            ok = False
        if not ok:  # one message at a time, for the first one's exact complaint
            seen: set[int] = set()
            for p in payloads:
                tr = cls.unpack(p, cfg)
                if (tr.ep, tr.t) != (ep, t) or tr.robot in seen:
                    raise BadMessage(f"bundle holds a message of robot {tr.robot} that does "
                                     "not fit")
                seen.add(tr.robot)
            raise BadMessage("bundle does not fit")  # (unreachable: some check above failed)
        return [cls(*row) for row in rows]


@dataclass
class Bundle:
    """Radio -> robot `robot`: the (already validated) trajectory payloads it heard at tick `t`;
    with `succ`, the robots whose predecessor it is this tick, to which it sends its hidden-state
    message itself (the radio's fast lane: virtual clock, no link fault; None: the radio
    forwards it)."""

    ep: int
    t: int
    robot: int
    trajs: list[bytes]
    succ: list[int] | None = None

    def pack(self) -> bytes:
        if self.succ is None:
            return _pack(K_BUNDLE, self.ep, self.t, self.robot, self.trajs)
        return _pack(K_BUNDLE, self.ep, self.t, self.robot, self.trajs, self.succ)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> Bundle:
        ep, t, robot, trajs, *rest = _unpack(payload, K_BUNDLE, (4, 5))
        if not isinstance(trajs, list) or len(trajs) > cfg.n_robots or not all(
                isinstance(b, bytes) for b in trajs):
            raise BadMessage("trajs must be a list of at most N payloads")
        robot = _int(robot, "robot", 0, cfg.n_robots - 1)
        succ = rest[0] if rest else None
        if succ is not None and (not isinstance(succ, list) or len(succ) >= cfg.n_robots):
            raise BadMessage("succ must be a list of fewer than N robot ids")
        if succ is not None:
            succ = [_int(i, "succ", robot + 1, cfg.n_robots - 1) for i in succ]
            if len(set(succ)) != len(succ):
                raise BadMessage("succ repeats a robot id")
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon), robot, trajs, succ)


@dataclass
class Hidden:
    """Robot -> its successors: CommAttn's decoder state s_i and action a_i (SPEC 3.5)."""

    ep: int
    t: int
    robot: int
    action: int
    state: bytes  # float32 little-endian vector

    def pack(self) -> bytes:
        return _pack(K_HIDDEN, self.ep, self.t, self.robot, self.action, self.state)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig, state_dim: int | None = None) -> Hidden:
        ep, t, robot, action, state = _unpack(payload, K_HIDDEN, 5)
        if not isinstance(state, bytes) or len(state) % 4:
            raise BadMessage("state must be float32 bytes")
        if state_dim is not None and len(state) != 4 * state_dim:
            raise BadMessage(f"state has {len(state) // 4} floats, expected {state_dim}")
        if len(state) > 4 * 4096 or not (np.abs(np.frombuffer(state, "<f4")) <= 1e6).all():
            raise BadMessage("state must be at most 4096 finite floats of magnitude <= 1e6")
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon),
                   _int(robot, "robot", 0, cfg.n_robots - 1), _int(action, "action", 0, 8), state)

    def vector(self) -> np.ndarray:
        return np.frombuffer(self.state, dtype="<f4")

    @classmethod
    def miss(cls, ep: int, t: int, robot: int) -> Hidden:
        """Radio -> successor: robot's hidden-state message of this tick will not come (lost or
        late in virtual time): decode without it now instead of waiting."""
        return cls(ep, t, robot, 0, b"")

    @property
    def is_miss(self) -> bool:
        return not self.state


K_STAMPED, DROPPED_Q = 20, -1.0  # (kept apart from the range above) queue of a dropped message


@dataclass
class Stamped:
    """Robot -> every robot (direct delivery): its packed Traj or Hidden (`kind`) with the ms it
    waited in its own token bucket, or DROPPED_Q; receivers draw every other fate themselves."""

    kind: int
    ep: int
    t: int
    robot: int
    queue_ms: float
    payload: bytes

    def pack(self) -> bytes:
        return _pack(K_STAMPED, self.kind, self.ep, self.t, self.robot, self.queue_ms, self.payload)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> Stamped:
        kind, ep, t, robot, q, inner = _unpack(payload, K_STAMPED, 6)
        if kind not in (K_TRAJ, K_HIDDEN) or isinstance(kind, bool):
            raise BadMessage(f"stamped kind {kind!r} is neither a trajectory nor a hidden state")
        q = _float(q, "queue_ms", DROPPED_Q, MAX_MS)
        if q < 0 and q != DROPPED_Q:
            raise BadMessage(f"queue_ms={q!r} neither >= 0 nor {DROPPED_Q}")
        if not isinstance(inner, bytes) or len(inner) > 4 * 4096 + 4 * cfg.cells + 1024:
            raise BadMessage("payload must be the bytes of one message")
        return cls(kind, _int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon),
                   _int(robot, "robot", 0, cfg.n_robots - 1), q, inner)


@dataclass
class Action:
    """Robot -> world: its action for tick `t`, and how long it took to plan. In direct delivery
    also whom it heard this tick (`heard`, np.packbits of N bools: the links the dashboard
    shows, which no radio saw) and, under a bandwidth cap in virtual time, its own token bucket
    after this tick's sends, which the world hands back in its next observation (`Obs.bucket`)
    so that a restarted robot goes on with it, as the radio's bucket for it would have."""

    ep: int
    t: int
    robot: int
    action: int
    planning_ms: float
    bucket: tuple[float, float] | None = None
    heard: bytes = b""

    def pack(self) -> bytes:
        tail: tuple[Any, ...] = (list(self.bucket or ()), self.heard)
        while tail and not tail[-1]:
            tail = tail[:-1]
        return _pack(K_ACTION, self.ep, self.t, self.robot, self.action, self.planning_ms, *tail)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> Action:
        ep, t, robot, action, planning_ms, *rest = _unpack(payload, K_ACTION, (5, 6, 7))
        heard = rest[1] if len(rest) > 1 else b""
        if heard != b"":
            heard = _bytes(heard, "heard", (cfg.n_robots + 7) // 8)
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon - 1),
                   _int(robot, "robot", 0, cfg.n_robots - 1), _int(action, "action", 0, 8),
                   _float(planning_ms, "planning_ms", 0.0, MAX_MS),
                   _bucket(rest[0] if rest else None), heard)


TICKED = (K_OBS, K_TRAJ, K_BUNDLE, K_HIDDEN, K_ACTION)
"""The kinds of message of one tick: `[SCHEMA, kind, ep, t, ...]`."""


def peek_tick(payload: bytes, kind: int | None = None) -> tuple[int, int] | None:
    """(ep, t) of a message of one tick (`TICKED`; a `Stamped`: its inner message's), of `kind`
    if given, read from its head without decoding the rest (for readers that only file or
    answer a message by its tick); None if it is not one (its tick unchecked against a run)."""
    try:
        u = msgpack.Unpacker(raw=False, max_buffer_size=len(payload) + 1)
        u.feed(payload)
        head = [u.unpack() for _ in range(min(u.read_array_header(), 5))]
    except Exception:  # msgpack raises several types; all mean "not msgpack"
        return None
    if len(head) == 5 and type(head[1]) is int and head[1] == K_STAMPED:
        del head[1]  # [SCHEMA, inner kind, ep, t]
    ok = len(head) >= 4 and all(type(v) is int for v in head[:4]) and head[0] == SCHEMA and \
        head[1] in TICKED and kind in (None, head[1]) and 0 <= min(head[2:4]) <= max(head[2:4]) \
        <= BIG
    return (head[2], head[3]) if ok else None


def pack_record(kind: int, record: dict[str, Any]) -> bytes:
    """Status, result and control records: a msgpack map (read by dashboards and other clients)."""
    return _pack(kind, record)


def unpack_record(payload: bytes, kind: int) -> dict[str, Any]:
    (record,) = _unpack(payload, kind, 1)
    if not isinstance(record, dict):
        raise BadMessage("record must be a map")
    return record
