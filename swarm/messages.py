"""The msgpack schemas of every message of a run; nothing else packs or unpacks a payload.

Each payload is a msgpack array `[SCHEMA, kind, ...fields]`. `unpack` validates types, ranges
and sizes against the run's world config and raises `BadMessage` (a one-line reason); the
callers drop and count such payloads, they never crash. Trajectory messages are compact: the
visited bitmap is bit-packed (H*W/8 bytes) and the patch is v*v bytes, 108 bytes in all on the
default 20 x 20 map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

from world.config import WorldConfig

SCHEMA = 1
K_OBS, K_TRAJ, K_BUNDLE, K_HIDDEN, K_ACTION, K_STATUS, K_RSTATUS, K_RESULT, K_CONTROL = range(9)


class BadMessage(ValueError):
    """A payload that does not decode or does not fit its schema."""


def _pack(kind: int, *fields: Any) -> bytes:
    return msgpack.packb([SCHEMA, kind, *fields], use_bin_type=True)


def _unpack(payload: bytes, kind: int, n_fields: int) -> list[Any]:
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
    if len(obj) != 2 + n_fields:
        raise BadMessage(f"{len(obj) - 2} fields, expected {n_fields}")
    return obj[2:]


def _int(v: Any, name: str, lo: int, hi: int) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise BadMessage(f"{name}={v!r} not an integer in [{lo}, {hi}]")
    return v


def _float(v: Any, name: str) -> float:
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
        raise BadMessage(f"{name}={v!r} not a finite number")
    return float(v)


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

    def pack(self) -> bytes:
        return _pack(K_OBS, self.ep, self.t, self.robot, self.y, self.x, self.patch, self.reward,
                     self.done, self.budget_ms)

    @classmethod
    def unpack(cls, payload: bytes, cfg: WorldConfig) -> Obs:
        ep, t, robot, y, x, patch, reward, done, budget = _unpack(payload, K_OBS, 9)
        if not isinstance(done, bool):
            raise BadMessage("done must be a bool")
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon),
                   _int(robot, "robot", 0, cfg.n_robots - 1), _int(y, "y", 0, cfg.height - 1),
                   _int(x, "x", 0, cfg.width - 1), _bytes(patch, "patch", cfg.vision ** 2),
                   _float(reward, "reward"), done, _float(budget, "budget_ms"))


@dataclass
class Traj:
    """Robot -> radio: the trajectory message of SPEC section 3 (what a receiver's encoder needs)."""

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
        recent = [_int(c, "recent cell", 0, cfg.cells - 1) for c in recent]
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon),
                   _int(robot, "robot", 0, cfg.n_robots - 1), _int(y, "y", 0, cfg.height - 1),
                   _int(x, "x", 0, cfg.width - 1), _bytes(visited, "visited", (cfg.cells + 7) // 8),
                   recent, _bytes(patch, "patch", cfg.vision ** 2))

    def visited_bits(self, cells: int) -> np.ndarray:
        return np.unpackbits(np.frombuffer(self.visited, dtype=np.uint8), count=cells).astype(bool)


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
        return cls(_int(ep, "ep", 0, BIG), _int(t, "t", 0, cfg.horizon),
                   _int(robot, "robot", 0, cfg.n_robots - 1), _int(action, "action", 0, 8), state)

    def vector(self) -> np.ndarray:
        return np.frombuffer(self.state, dtype="<f4")


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
                   _float(planning_ms, "planning_ms"))


def pack_record(kind: int, record: dict[str, Any]) -> bytes:
    """Status, result and control records: a msgpack map (read by dashboards and other clients)."""
    return _pack(kind, record)


def unpack_record(payload: bytes, kind: int) -> dict[str, Any]:
    (record,) = _unpack(payload, kind, 1)
    if not isinstance(record, dict):
        raise BadMessage("record must be a map")
    return record
