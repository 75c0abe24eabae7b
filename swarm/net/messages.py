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


ATTN_SUM_TOL = 1e-3  # attention weights are float32 softmax outputs, sent rounded


RSTATUS_COUNTS = ("msgs_in", "msgs_out", "bytes_in", "bytes_out", "bad", "stale", "missed",
                  "missed_hidden", "version", "weights_bad", "weights_late", "rollouts_lost",
                  "stalls", "rejoins", "errors", "oversized", "overflow")
"""A robot status's counters: non-negative integers."""


def check_robot_status(rec: dict[str, Any], n_robots: int, horizon: int) -> dict[str, Any]:
    """A robot status record's id and its optional attention fields, range-checked (BadMessage
    otherwise: the consumer drops and counts the record). `attn` is the robot's attention
    weights over the team, [N] numbers in [0, 1], zero for members it did not hear, summing to 1
    (it always hears itself); `attn_t` the tick they were computed at. Both or neither."""
    _int(rec.get("robot"), "robot", 0, n_robots - 1)
    _int(rec.get("ep", -1), "ep", -1, 2**31 - 1)  # (-1: before its first episode)
    for k in RSTATUS_COUNTS:  # (the dashboard and the result read them: no half-applied record)
        if k in rec:
            _int(rec[k], k, 0, 2**53)
    for k in ("latency_ms", "compute_ms", "wait_ms"):
        if k in rec:
            _float(rec[k], k, 0.0, MAX_MS)
    if not isinstance(rec.get("final", False), bool):
        raise BadMessage("final must be true or false")
    if "attn" not in rec and "attn_t" not in rec:
        return rec
    w = rec.get("attn")
    if not isinstance(w, list) or len(w) != n_robots:
        raise BadMessage(f"attn must be a list of {n_robots} weights")
    total = sum(_float(x, "attn weight", 0.0, 1.0) for x in w)
    if abs(total - 1.0) > ATTN_SUM_TOL * max(1, n_robots):
        raise BadMessage(f"attn weights sum to {total:.4f}, not 1")
    _int(rec.get("attn_t"), "attn_t", 0, horizon)
    return rec


def _cells(v: Any, name: str, cfg: WorldConfig, most: int) -> None:
    """A list of at most `most` [y, x] cells on the grid."""
    if not isinstance(v, list) or len(v) > most:
        raise BadMessage(f"{name} must be a list of at most {most} cells")
    if not v:
        return
    try:  # (one array, not a Python check per cell: the supervisor reads one status a tick)
        a = np.array(v)
    except ValueError:  # ragged
        a = np.zeros(0)
    if a.dtype.kind not in "iu" or a.shape != (len(v), 2) or (a < 0).any() or \
            (a[:, 0] >= cfg.height).any() or (a[:, 1] >= cfg.width).any():
        raise BadMessage(f"{name} must be [y, x] integer cells on the {cfg.height} x "
                         f"{cfg.width} grid")


def check_world_status(rec: dict[str, Any], cfg: WorldConfig, first_episode: int,
                       episodes: int) -> dict[str, Any]:
    """A world status record (swarm.procs.world.WorldProcess._status) with every field its
    readers use in range: the supervisor (whose process faults fire on `run_tick`), the
    dashboard, the replay. BadMessage (one line) otherwise; the reader drops and counts it."""
    n = cfg.n_robots
    _int(rec.get("ep"), "status ep", first_episode, first_episode + episodes - 1)
    _int(rec.get("t"), "status t", 0, cfg.horizon)
    run_tick = _int(rec.get("run_tick"), "status run_tick", 0, episodes * (cfg.horizon + 1))
    if run_tick != (rec["ep"] - first_episode) * cfg.horizon + rec["t"]:
        raise BadMessage(f"status run_tick {run_tick} is not episode {rec['ep']} tick "
                         f"{rec['t']}'s")
    _cells(rec.get("pos"), "status pos", cfg, n)
    alive = rec.get("alive")
    if not isinstance(alive, list) or len(alive) != n or \
            not all(isinstance(a, bool) for a in alive):
        raise BadMessage(f"status alive must be {n} booleans")
    _float(rec.get("elratio"), "status elratio", 0.0, 1.0)
    for k in ("block_coll", "robot_coll", "bad", "late", "heard_links"):
        _int(rec.get(k, 0), f"status {k}", 0, BIG)
    _cells(rec.get("dyn", []), "status dyn", cfg, cfg.cells)
    _cells(rec.get("static", []), "status static", cfg, cfg.cells)
    timeouts = rec.get("timeouts", [])
    if not isinstance(timeouts, list) or len(timeouts) > n:
        raise BadMessage(f"status timeouts must be a list of at most {n} robots")
    _ints(timeouts, "status timeouts", 0, n - 1)
    _float(rec.get("vtime", 0.0), "status vtime", 0.0, 1e12)
    if rec.get("clock", "virtual") not in ("virtual", "real"):
        raise BadMessage("status clock must be virtual or real")
    _status_panels(rec, n)
    return rec


def _status_panels(rec: dict[str, Any], n: int) -> None:
    """A status's fault lines, radio counts and faulted links as the dashboard and `swarm
    trace` read them (a list of ints for a link, a string for a fault line: one of another
    shape crashed the supervisor's display and `swarm replay`)."""
    faults, radio, links = rec.get("faults", []), rec.get("radio", {}), rec.get("links", {})
    if not isinstance(faults, list) or len(faults) > 64 or \
            not all(isinstance(f, str) and len(f) <= 400 for f in faults):
        raise BadMessage("status faults must be at most 64 lines of text")
    if not isinstance(radio, dict) or len(radio) > 64 or not all(
            isinstance(k, str) and (isinstance(v, dict) and len(v) <= 16  # (by_kind)
                                    or isinstance(v, list) and len(v) <= n  # (reported)
                                    or type(v) in (int, float) and 0 <= v <= 1e18)
            for k, v in radio.items()):
        raise BadMessage("status radio must be at most 64 counts (numbers >= 0) by name")
    if not isinstance(links, dict) or len(links) > n * n:
        raise BadMessage(f"status links must hold at most {n * n} links")
    for k, v in links.items():
        j, sep, i = str(k).partition("-")
        if not (sep and j.isdigit() and i.isdigit() and int(j) < n and int(i) < n) or \
                not isinstance(v, list) or len(v) != 4:
            raise BadMessage(f'status links: {str(k)[:20]!r} is no "SENDER-RECEIVER" of 4 '
                             "counts")
        _ints(v, f"status links {k}", 0, BIG)


RESULT_COUNTS = ("elratio_std", "reward_std", "collisions_mean", "block_collisions_mean",
                 "planning_ms_per_decision", "ticks_per_s", "timeouts", "robots_lost")


def check_world_result(rec: dict[str, Any], policy: str, episodes: int, run_id: str,
                       horizon: int) -> dict[str, Any]:
    """The world's result: this run's id and policy, at most the episodes asked, as many
    action logs of `horizon` ticks, its ticks and counts, every figure its readers format a
    number (BadMessage: a stray neither ends a run nor crashes its table; `--secure` for more)."""
    for k, want in (("run_id", run_id), ("policy", policy)):
        if rec.get(k) != want:
            raise BadMessage(f"a result of {k} {rec.get(k)!r}, not {want!r}")
    done = _int(rec.get("completed"), "result completed", 0, episodes)
    for k, lo, hi in (("elratio_mean", 0, 1), ("success_rate", 0, 1), ("reward_mean", -1e9, 1e9),
                      *((k, 0, 1e9) for k in RESULT_COUNTS)):
        if done or (v := rec.get(k, 0)) is not None and v == v:  # (none done: NaN, None means)
            _float(rec.get(k, 0), f"result {k}", lo, hi)
    actions = rec.get("actions")
    if not isinstance(actions, list) or len(actions) != done or \
            not all(isinstance(a, list) and len(a) == horizon for a in actions):
        raise BadMessage(f"result actions are not {done} episode(s) of {horizon} ticks")
    _int(rec.get("ticks"), "result ticks", done * horizon, episodes * horizon)
    if isinstance(rec.get("messages"), dict):
        return rec
    raise BadMessage("result without its message counts")
