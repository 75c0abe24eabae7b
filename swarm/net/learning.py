"""The learning messages of a run (weights, robots' episode records, the world's rewards,
rollout workers' episodes), with the same conventions as swarm.net.messages: msgpack arrays
`[SCHEMA, kind, ...]`, every field checked on unpack, `BadMessage` (one line) otherwise."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from swarm.net.messages import (
    BIG,
    K_EPISODE,
    K_EROLLOUT,
    K_RROLLOUT,
    K_WEIGHTS,
    BadMessage,
    _bytes,
    _float,
    _int,
    _pack,
    _unpack,
)
from world.config import WorldConfig
from world.core import METRIC_NAMES

MAX_ARRAY_BYTES = 64 << 20  # (a payload itself is at most 4 MB: swarm.net.inbox)


def _array(v: Any, name: str, dtype: str, shape: tuple[int, ...],
           finite: bool = False) -> np.ndarray:
    """A fixed-size little-endian array from bytes (copied: the result is writable); the size
    in Python integers (numpy's product of a hostile shape wraps, to 0 for [65536] * 4);
    `finite`: NaN and infinities are refused."""
    size = math.prod(shape) * np.dtype(dtype).itemsize
    if size > MAX_ARRAY_BYTES:
        raise BadMessage(f"{name}: shape {list(shape)} is {size} bytes, over {MAX_ARRAY_BYTES}")
    out = np.frombuffer(_bytes(v, name, size), dtype=dtype).reshape(shape).copy()
    if finite and not np.isfinite(out).all():
        raise BadMessage(f"{name} is not finite (NaN or infinite values)")
    return out


def _bits(v: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A bool array packed with np.packbits along its last axis."""
    *lead, last = shape
    packed = _array(v, name, "u1", (*lead, (last + 7) // 8))
    return np.unpackbits(packed, axis=-1, count=last).astype(bool)



def _metrics(v: Any) -> dict[str, float]:
    if not isinstance(v, dict) or set(v) != set(METRIC_NAMES):
        raise BadMessage(f"metrics must be a map of {', '.join(METRIC_NAMES)}")
    return {k: _float(v[k], f"metrics.{k}") for k in METRIC_NAMES}


def reward_limit(cfg: WorldConfig) -> float:
    """The largest |reward| a robot can get in one step of `cfg` (`world.core.step`: one
    step back, a collision with each other robot, the end's success or failure), plus one: a
    reward past it is no reward of this world (3e38 made every loss and its status infinite)."""
    return (abs(cfg.r_back) + cfg.n_robots * abs(cfg.r_coll) + max(abs(cfg.r_succ),
                                                                   abs(cfg.r_fail)) + 1.0)


def _rewards(a: np.ndarray, name: str, cfg: WorldConfig) -> np.ndarray:
    lim = reward_limit(cfg)
    if not (np.isfinite(a).all() and (np.abs(a) <= lim).all()):
        raise BadMessage(f"{name} must be finite rewards within +-{lim:g} (this world's)")
    return a


def heard_of(heard: bytes, n: int) -> np.ndarray:
    """A robot's heard ids ([n] bool) from its packed record (`RolloutTick.heard`)."""
    return np.unpackbits(np.frombuffer(heard, np.uint8), count=n).astype(bool)


@dataclass
class Weights:
    """Learner -> robots and workers: version `version` of the shared weights of `policy`."""

    policy: str
    version: int
    model: dict[str, Any]  # the network's config dataclass as a dict
    tensors: dict[str, np.ndarray]  # float32 state_dict
    origin: int = 0
    """Which learner process publishes them (drawn at its start): a worker follows a learner
    that replaced the one it knew, whatever its versions (they start again from its own)."""

    def pack(self) -> bytes:
        data = {k: [list(a.shape), np.ascontiguousarray(a, "<f4").tobytes()]
                for k, a in self.tensors.items()}
        return _pack(K_WEIGHTS, self.policy, self.version, self.model, data, self.origin)

    def newer_than(self, version: int, origin: int) -> bool:
        """Whether a holder of `version` from learner `origin` should take these."""
        return self.origin != origin or self.version > version

    @classmethod
    def unpack(cls, payload: bytes) -> Weights:
        policy, version, model, data, *rest = _unpack(payload, K_WEIGHTS, (4, 5))
        if not isinstance(policy, str) or not isinstance(model, dict) or not isinstance(data, dict):
            raise BadMessage("weights need a policy name, a model map and a tensor map")
        tensors = {}
        for k, v in data.items():
            if not (isinstance(k, str) and isinstance(v, list) and len(v) == 2
                    and isinstance(v[0], list) and all(isinstance(d, int) and 0 <= d < 2**20
                                                       for d in v[0])):
                raise BadMessage(f"tensor {k!r} must be [shape, float32 bytes]")
            tensors[k] = _array(v[1], f"tensor {k}", "<f4", tuple(v[0]), finite=True)
        return cls(policy, _int(version, "version", 0, BIG), model, tensors,
                   _int(rest[0], "origin", 0, BIG) if rest else 0)


class RolloutTick(NamedTuple):
    """One tick of a robot's episode record (see RobotRollout)."""

    traj: bytes  # the trajectory payload it published (as every receiver got it)
    heard: bytes  # the ids whose messages it heard, np.packbits of [N] bool (`heard_of`; an
    # int mask overflowed msgpack past 64 robots and numpy's int64 at 64)
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
    heard (packed bits, its own among them), whether its predecessor's hidden-state message
    arrived, the action it sent, its log-probability, the reward of the previous step and the
    weights version used."""

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
            lim = reward_limit(cfg)
            out.append(RolloutTick(
                rec[0], _bytes(rec[1], "heard", (cfg.n_robots + 7) // 8), rec[2],
                _int(rec[3], "action", 0, 8), _float(rec[4], "logp", -1e4, 0.0),
                _float(rec[5], "last_reward", -lim, lim), _int(rec[6], "version", 0, BIG)))
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
        return cls(_int(ep, "ep", 0, BIG),
                   _rewards(_array(reward, "reward", "<f4", (t, n)), "reward", cfg),
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
            logp=_array(get("logp"), "logp", "<f4", (t, n)),  # (needed: PPO, stale episodes)
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
        _rewards(out.reward, "reward", cfg)
        _rewards(out.last_reward, "last_reward", cfg)
        if not (np.isfinite(out.logp).all() and (out.logp <= 0).all()):
            raise BadMessage("log-probabilities must be finite and <= 0")
        return check_decisions(out, every_tick=True)  # (a batched episode: every robot acts)


def check_decisions(e: EpisodeRollout, every_tick: bool) -> EpisodeRollout:
    """An episode the update can take: every robot that acted heard its own message (the
    features read its own row of what it heard: without it the learner crashed), and with
    `every_tick` some robot acted at every tick (a swarm's episode may have a tick where every
    robot was late or down: the learner keeps it out of a batch no other episode covers)."""
    n = e.hears.shape[-1]
    quiet = ~e.receivers.any(1)
    if every_tick and quiet.any():
        raise BadMessage(f"episode {e.ep}: no robot acted at tick {int(np.argmax(quiet))}")
    own = e.hears[:, np.arange(n), np.arange(n)]
    if (e.receivers & ~own).any():
        t, i = map(int, np.argwhere(e.receivers & ~own)[0])
        raise BadMessage(f"episode {e.ep}: robot {i} acted at tick {t} without its own message")
    return e


# ------------------------------------------------------------------- the learner's status
LSTATUS_COUNTS = ("version", "episodes", "updates", "pending", "ready", "stale_used",
                  "stale_dropped", "incomplete", "bad", "worker_episodes", "rollout_bytes",
                  "late_records", "oversized", "overflow")
ACCOUNTING = ("received", "trained", "pending", "stale_dropped", "incomplete", "rejected",
              "lost")
MAX_COUNT = 2**62


def check_learner_status(rec: dict[str, Any]) -> dict[str, Any]:
    """A learner status record (swarm.procs.learning.learner.Learner.status) with every field
    its readers use in range: the supervisor's dashboard and result, a lockstep world.
    BadMessage (one line) otherwise; the reader drops and counts it."""
    for name in LSTATUS_COUNTS:
        _int(rec.get(name, 0), f"learner status {name}", 0, MAX_COUNT)
    _int(rec.get("last_closed", -1), "learner status last_closed", -1, MAX_COUNT)
    _int(rec.get("origin", 0), "learner status origin", 0, BIG)
    if not isinstance(rec.get("update_due", False), bool):
        raise BadMessage("learner status update_due must be a bool")
    _float(rec.get("rollout_bytes_per_s", 0.0), "learner status rollout_bytes_per_s", 0.0, 1e15)
    curve = rec.get("curve", [])
    if not isinstance(curve, list) or len(curve) > 40:
        raise BadMessage("learner status curve must be a list of at most 40 numbers")
    for x in curve:
        _float(x, "learner status curve value", -1e9, 1e9)
    last = rec.get("last") or {}
    acc = rec.get("accounting") or {}
    if not isinstance(last, dict) or not isinstance(acc, dict):
        raise BadMessage("learner status last and accounting must be maps")
    for k in ("elratio", "reward", "loss"):
        if last.get(k) is not None:
            _float(last[k], f"learner status last {k}")
    for k in ACCOUNTING:
        _int(acc.get(k, 0), f"learner status accounting {k}", 0, MAX_COUNT)
    return rec


# ------------------------------------------------------------------- lockstep field training
@dataclass
class LearnerGate:
    """Lockstep field training (`RunConfig.train_sync`, `swarm run --train --train-sync`): what
    the world knows of its learner's progress, from the learner's status records.

    Without lockstep, field training is asynchronous, as in IMPALA-style actor-learner systems:
    robots play on while the learner trains and adopt a new version at their next episode
    boundary, so which episodes land in which update (and how stale each is) depends on how fast
    each process runs, and a run is not a function of its seed. With it, the world starts
    episode e only when the learner has settled every episode before e (joined into its batch,
    or counted incomplete, rejected or stale) and made any update due; tick 0's observations
    name the learner's version, and a robot that has not got it fetches it before acting
    (`RobotProcess.catch_up`). Every episode is played with the weights of all before it, as the
    batched trainer's on-policy batches are, and two runs with one seed train the same weights;
    the price is that robots idle while the learner joins each episode and runs each update.
    The status record is hostile input like any message: each field is range-checked here."""

    first_episode: int
    version: int | None = None  # None until a status record came
    origin: int = 0  # the learner process it came from (a fresh one counts versions anew)
    last_closed: int = -1
    joining: int = 0
    update_due: bool = False
    waits: int = 0  # episodes the world held back for the learner
    wait_s: float = 0.0  # wall seconds it held them, summed
    timeouts: int = 0  # episodes started anyway after the wait limit (the run is not lockstep)

    def offer(self, rec: dict[str, Any]) -> None:
        """Take a learner status record; BadMessage (nothing kept) unless it is whole and every
        field is in range."""
        if not {"version", "last_closed", "pending", "update_due"} <= set(rec):
            raise BadMessage("learner status without version, last_closed, pending, update_due")
        check_learner_status(rec)
        origin = rec.get("origin", 0)
        if self.version is not None and rec["version"] < self.version and origin == self.origin:
            return  # an older record overtaken by a newer one: a learner's versions only grow
        self.version, self.last_closed = rec["version"], rec["last_closed"]
        self.origin = origin  # (a learner that replaced the last one: its own versions)
        self.joining, self.update_due = rec["pending"], rec["update_due"]

    def version_for(self, ep: int) -> int | None:
        """The version episode `ep` is to be played with, None while the learner is behind."""
        if self.version is None or self.joining or self.update_due:
            return None
        if ep > self.first_episode and self.last_closed < ep - 1:
            return None
        return self.version

    def wait(self, ep: int, pump: Callable[[float], bool], limit: float,
             stop: Callable[[], bool]) -> int | None:
        """Pump the world's events until the learner is ready for `ep` (its version) or `limit`
        seconds passed (None, counted in `timeouts`)."""
        start = time.monotonic()
        deadline = start + limit
        held = False
        while (v := self.version_for(ep)) is None and not stop() and \
                time.monotonic() < deadline:
            held = True
            pump(min(deadline, time.monotonic() + 0.05))
        self.waits += held
        self.wait_s += time.monotonic() - start
        if v is None and not stop():
            self.timeouts += 1
        return v

    def summary(self) -> dict[str, Any]:
        return {"waits": self.waits, "wait_s": round(self.wait_s, 3), "timeouts": self.timeouts,
                "version": self.version}
