"""The msgpack schemas of every message of a run; nothing else packs or unpacks a payload.

Each payload is a msgpack array `[SCHEMA, kind, ...fields]`. `unpack` validates types, ranges
and sizes against the run's world config and raises `BadMessage` (a one-line reason); the
callers drop and count such payloads, they never crash. Trajectory messages are compact: the
visited bitmap is bit-packed (H*W/8 bytes) and the patch is v*v bytes, 108 bytes in all on the
default 20 x 20 map.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import msgpack
import numpy as np

from world.config import WorldConfig
from world.core import METRIC_NAMES

SCHEMA = 1
(K_OBS, K_TRAJ, K_BUNDLE, K_HIDDEN, K_ACTION, K_STATUS, K_RSTATUS, K_RESULT, K_CONTROL,
 K_WEIGHTS, K_RROLLOUT, K_EPISODE, K_EROLLOUT, K_LSTATUS) = range(14)


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
    if obj[0] != SCHEMA:
        raise BadMessage(f"schema version {obj[0]!r}, expected {SCHEMA}")
    if obj[1] != kind:
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


MAX_MS = 3.6e6  # an hour: the longest duration any message may carry


def _bytes(v: Any, name: str, size: int) -> bytes:
    if not isinstance(v, bytes) or len(v) != size:
        raise BadMessage(f"{name} must be {size} bytes")
    return v


BIG = 2**31 - 1


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

    def pack(self) -> bytes:
        return _pack(K_OBS, self.ep, self.t, self.robot, self.y, self.x, self.patch, self.reward,
                     self.done, self.budget_ms, *((self.live,) if self.live else ()))

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> Obs:
        ep, t, robot, y, x, patch, reward, done, budget, *live = _unpack(payload, K_OBS, (9, 10))
        if not isinstance(done, bool):
            raise BadMessage("done must be a bool")
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon),
                   _int(robot, "robot", 0, cfg.n_robots - 1), _int(y, "y", 0, cfg.height - 1),
                   _int(x, "x", 0, cfg.width - 1), _bytes(patch, "patch", cfg.vision ** 2),
                   _float(reward, "reward"), done, _float(budget, "budget_ms", 0.0, MAX_MS),
                   _bytes(live[0], "live", (cfg.n_robots + 7) // 8) if live else b"")


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
    """Radio -> robot `robot`: the (already validated) trajectory payloads it heard at tick `t`."""

    ep: int
    t: int
    robot: int
    trajs: list[bytes]

    def pack(self) -> bytes:
        return _pack(K_BUNDLE, self.ep, self.t, self.robot, self.trajs)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> Bundle:
        ep, t, robot, trajs = _unpack(payload, K_BUNDLE, 4)
        if not isinstance(trajs, list) or len(trajs) > cfg.n_robots or not all(
                isinstance(b, bytes) for b in trajs):
            raise BadMessage("trajs must be a list of at most N payloads")
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon),
                   _int(robot, "robot", 0, cfg.n_robots - 1), trajs)


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
    """Robot -> world: its action for tick `t`, and how long it took to plan."""

    ep: int
    t: int
    robot: int
    action: int
    planning_ms: float

    def pack(self) -> bytes:
        return _pack(K_ACTION, self.ep, self.t, self.robot, self.action, self.planning_ms)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> Action:
        ep, t, robot, action, planning_ms = _unpack(payload, K_ACTION, 5)
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon - 1),
                   _int(robot, "robot", 0, cfg.n_robots - 1), _int(action, "action", 0, 8),
                   _float(planning_ms, "planning_ms", 0.0, MAX_MS))


def pack_record(kind: int, record: dict[str, Any]) -> bytes:
    """Status, result and control records: a msgpack map (read by dashboards and other clients)."""
    return _pack(kind, record)


def unpack_record(payload: bytes, kind: int) -> dict[str, Any]:
    (record,) = _unpack(payload, kind, 1)
    if not isinstance(record, dict):
        raise BadMessage("record must be a map")
    return record


ATTN_SUM_TOL = 1e-3  # attention weights are float32 softmax outputs, sent rounded


def check_robot_status(rec: dict[str, Any], n_robots: int, horizon: int) -> dict[str, Any]:
    """A robot status record's id and its optional attention fields, range-checked (BadMessage
    otherwise: the consumer drops and counts the record). `attn` is the robot's attention
    weights over the team, [N] numbers in [0, 1], zero for members it did not hear, summing to 1
    (it always hears itself); `attn_t` the tick they were computed at. Both or neither."""
    _int(rec.get("robot"), "robot", 0, n_robots - 1)
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


# ------------------------------------------------------------------- learning (issue: learner)
def _array(v: Any, name: str, dtype: str, shape: tuple[int, ...]) -> np.ndarray:
    """A fixed-size little-endian array from bytes (copied: the result is writable)."""
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    return np.frombuffer(_bytes(v, name, size), dtype=dtype).reshape(shape).copy()


def _bits(v: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A bool array packed with np.packbits along its last axis."""
    *lead, last = shape
    packed = _array(v, name, "u1", (*lead, (last + 7) // 8))
    return np.unpackbits(packed, axis=-1, count=last).astype(bool)



def _metrics(v: Any) -> dict[str, float]:
    if not isinstance(v, dict) or set(v) != set(METRIC_NAMES):
        raise BadMessage(f"metrics must be a map of {', '.join(METRIC_NAMES)}")
    return {k: _float(v[k], f"metrics.{k}") for k in METRIC_NAMES}


@dataclass
class Weights:
    """Learner -> robots and workers: version `version` of the shared weights of `policy`."""

    policy: str
    version: int
    model: dict[str, Any]  # the network's config dataclass as a dict
    tensors: dict[str, np.ndarray]  # float32 state_dict

    def pack(self) -> bytes:
        data = {k: [list(a.shape), np.ascontiguousarray(a, "<f4").tobytes()]
                for k, a in self.tensors.items()}
        return _pack(K_WEIGHTS, self.policy, self.version, self.model, data)

    @classmethod
    def unpack(cls, payload: bytes) -> Weights:
        policy, version, model, data = _unpack(payload, K_WEIGHTS, 4)
        if not isinstance(policy, str) or not isinstance(model, dict) or not isinstance(data, dict):
            raise BadMessage("weights need a policy name, a model map and a tensor map")
        tensors = {}
        for k, v in data.items():
            if not (isinstance(k, str) and isinstance(v, list) and len(v) == 2
                    and isinstance(v[0], list) and all(isinstance(d, int) and 0 <= d < 2**20
                                                       for d in v[0])):
                raise BadMessage(f"tensor {k!r} must be [shape, float32 bytes]")
            tensors[k] = _array(v[1], f"tensor {k}", "<f4", tuple(v[0]))
        return cls(policy, _int(version, "version", 0, BIG), model, tensors)


class RolloutTick(NamedTuple):
    """One tick of a robot's episode record (see RobotRollout)."""

    traj: bytes  # the trajectory payload it published (as every receiver got it)
    heard: int  # bit mask of the ids whose messages it heard
    chain_ok: bool  # its predecessor's hidden-state message arrived
    action: int
    logp: float  # log-probability of the action under the weights that acted
    last_reward: float  # reward of the previous step
    version: int  # weights version that acted


@dataclass
class RobotRollout:
    """Robot -> learner, at the end of an episode: what it observed, heard and did, per tick.

    Each tick is `[traj, heard, chain_ok, action, logp, last_reward, version]`: the trajectory
    payload it published (its own message, as every receiver got it), the ids whose messages it
    heard as a bit mask, whether its predecessor's hidden-state message arrived, the action it
    sent, its log-probability, the reward of the previous step and the weights version used."""

    ep: int
    robot: int
    ticks: list[RolloutTick]

    def pack(self) -> bytes:
        return _pack(K_RROLLOUT, self.ep, self.robot, [list(t) for t in self.ticks])

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> RobotRollout:
        ep, robot, ticks = _unpack(payload, K_RROLLOUT, 3)
        if not isinstance(ticks, list) or len(ticks) > cfg.horizon:
            raise BadMessage(f"ticks must be a list of at most {cfg.horizon} records")
        out = []
        for rec in ticks:
            if not isinstance(rec, list) or len(rec) != 7 or not isinstance(rec[2], bool):
                raise BadMessage("a tick record is [traj, heard, chain_ok, action, logp, "
                                 "last_reward, version]")
            if not isinstance(rec[0], bytes):
                raise BadMessage("traj must be bytes")
            out.append(RolloutTick(
                rec[0], _int(rec[1], "heard", 0, 2 ** cfg.n_robots - 1), rec[2],
                _int(rec[3], "action", 0, 8), _float(rec[4], "logp", -1e4, 0.0),
                _float(rec[5], "last_reward"), _int(rec[6], "version", 0, BIG)))
        return cls(_int(ep, "ep", 0, BIG), _int(robot, "robot", 0, cfg.n_robots - 1), out)


@dataclass
class EpisodeRecord:
    """World -> learner, at the end of an episode: each robot's reward per tick, which robots
    acted in time (their action was applied), and the episode's metrics."""

    ep: int
    reward: np.ndarray  # [T, N] float32
    acted: np.ndarray  # [T, N] bool
    metrics: dict[str, float]

    def pack(self) -> bytes:
        return _pack(K_EPISODE, self.ep, int(self.reward.shape[0]),
                     np.ascontiguousarray(self.reward, "<f4").tobytes(),
                     np.packbits(self.acted, axis=-1).tobytes(), self.metrics)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> EpisodeRecord:
        ep, t, reward, acted, metrics = _unpack(payload, K_EPISODE, 5)
        t = _int(t, "ticks", 1, cfg.horizon)
        n = cfg.n_robots
        return cls(_int(ep, "ep", 0, BIG), _array(reward, "reward", "<f4", (t, n)),
                   _bits(acted, "acted", (t, n)), _metrics(metrics))


@dataclass
class EpisodeRollout:
    """One whole episode in the batched trainer's terms (what `swarm.learn.rollout.collect` records
    for one group), from the swarm's joined records or from a rollout worker. Arrays [T, N, ...]."""

    ep: int
    seed: int
    version: int
    pos: np.ndarray  # [T, N, 2] int64
    visited: np.ndarray  # [T, N, H*W] bool
    recent: np.ndarray  # [T, N, L] int64 (-1 none)
    patch: np.ndarray  # [T, N, v, v] uint8
    present: np.ndarray  # [T, N] bool
    hears: np.ndarray  # [T, N, N] bool
    receivers: np.ndarray  # [T, N] bool
    chain_ok: np.ndarray  # [T, N] bool
    last_reward: np.ndarray  # [T, N] float32
    actions: np.ndarray  # [T, N] int64
    reward: np.ndarray  # [T, N] float32
    metrics: dict[str, float]
    logp: np.ndarray | None = None  # [T, N] float32 log pi(a) of the acting weights (0 off
    # receivers); None from senders that did not record it (no importance correction then)

    def pack(self) -> bytes:
        a = {
            "pos": np.ascontiguousarray(self.pos, "<i2").tobytes(),
            "visited": np.packbits(self.visited, axis=-1).tobytes(),
            "recent": np.ascontiguousarray(self.recent, "<i2").tobytes(),
            "patch": np.ascontiguousarray(self.patch, "u1").tobytes(),
            "present": np.packbits(self.present, axis=-1).tobytes(),
            "hears": np.packbits(self.hears, axis=-1).tobytes(),
            "receivers": np.packbits(self.receivers, axis=-1).tobytes(),
            "chain_ok": np.packbits(self.chain_ok, axis=-1).tobytes(),
            "last_reward": np.ascontiguousarray(self.last_reward, "<f4").tobytes(),
            "actions": np.ascontiguousarray(self.actions, "u1").tobytes(),
            "reward": np.ascontiguousarray(self.reward, "<f4").tobytes(),
        }
        if self.logp is not None:
            a["logp"] = np.ascontiguousarray(self.logp, "<f4").tobytes()
        return _pack(K_EROLLOUT, self.ep, self.seed, self.version, int(self.pos.shape[0]), a,
                     self.metrics)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> EpisodeRollout:
        ep, seed, version, t, a, metrics = _unpack(payload, K_EROLLOUT, 6)
        t = _int(t, "ticks", 1, cfg.horizon)
        if not isinstance(a, dict):
            raise BadMessage("arrays must be a map")
        n, v, ll = cfg.n_robots, cfg.vision, cfg.recent_len
        get = a.get
        out = cls(
            _int(ep, "ep", 0, BIG), _int(seed, "seed", -BIG, BIG), _int(version, "version", 0, BIG),
            pos=_array(get("pos"), "pos", "<i2", (t, n, 2)).astype(np.int64),
            visited=_bits(get("visited"), "visited", (t, n, cfg.cells)),
            recent=_array(get("recent"), "recent", "<i2", (t, n, ll)).astype(np.int64),
            patch=_array(get("patch"), "patch", "u1", (t, n, v, v)),
            present=_bits(get("present"), "present", (t, n)),
            hears=_bits(get("hears"), "hears", (t, n, n)),
            receivers=_bits(get("receivers"), "receivers", (t, n)),
            chain_ok=_bits(get("chain_ok"), "chain_ok", (t, n)),
            last_reward=_array(get("last_reward"), "last_reward", "<f4", (t, n)),
            actions=_array(get("actions"), "actions", "u1", (t, n)).astype(np.int64),
            reward=_array(get("reward"), "reward", "<f4", (t, n)),
            metrics=_metrics(metrics),
            logp=None if get("logp") is None else _array(get("logp"), "logp", "<f4", (t, n)),
        )
        lim = np.array([cfg.height, cfg.width])
        if (out.pos < 0).any() or (out.pos >= lim).any():
            raise BadMessage("pos off the grid")
        if (out.recent < -1).any() or (out.recent >= cfg.cells).any():
            raise BadMessage("recent cell off the grid")
        if (out.actions > 8).any():
            raise BadMessage("action outside 0..8")
        if (out.receivers & ~out.present).any() or (out.hears & ~out.present[:, None, :]).any():
            raise BadMessage("a receiver or a heard member has no message")
        if not (np.isfinite(out.reward).all() and np.isfinite(out.last_reward).all()):
            raise BadMessage("rewards must be finite")
        if out.logp is not None and not (np.isfinite(out.logp).all() and (out.logp <= 0).all()):
            raise BadMessage("log-probabilities must be finite and <= 0")
        return out
