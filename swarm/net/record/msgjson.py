"""The JSON form of every message of a run, and its JSON Schema (for recordings: generic MCAP
tools and Foxglove read and plot JSON channels, not msgpack).

`to_json(kind, payload, cfg)` validates the payload with the schema classes of
`swarm.net.messages` (the same checks every process applies, so a payload that would be dropped
on the wire raises `BadMessage` here too) and returns a JSON-safe dict: numbers stay numbers,
small byte fields become lists of ints (patches) or base64 strings (bitmaps, nested payloads),
hidden states become float lists. `SCHEMAS[kind]` describes each form; `additionalProperties`
is left open on records (status, result, ...) whose fields grow over time. A kind without a
form of its own here (a key added later) gets `GENERIC`, and no JSON messages.
"""

from __future__ import annotations

import base64
import math
from typing import Any

import numpy as np

from swarm.net import learning
from swarm.net import messages as m
from swarm.net.records import check_robot_status
from world.config import WorldConfig

INT = {"type": "integer"}
NUM = {"type": "number"}
BOOL = {"type": "boolean"}
B64 = {"type": "string", "contentEncoding": "base64"}
INTS = {"type": "array", "items": INT}
NUMS = {"type": "array", "items": NUM}
HEAD = {"ep": INT, "t": INT, "robot": INT}


def _obj(props: dict[str, Any], title: str, closed: bool = True,
         optional: dict[str, Any] | None = None) -> dict[str, Any]:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title,
            "type": "object", "properties": props | (optional or {}), "required": sorted(props),
            "additionalProperties": not closed}


BUCKET = {"bucket": {"type": "array", "items": NUM, "minItems": 2, "maxItems": 2}}  # direct
# delivery under a cap: the robot's own token bucket [tokens, ms of its last charge]


TRAJ = _obj({**HEAD, "y": INT, "x": INT, "visited": B64, "visited_cells": INT,
             "recent": INTS, "patch": INTS}, "swarm trajectory message")
HIDDEN = _obj({**HEAD, "action": INT, "miss": BOOL, "state": NUMS},
              "swarm hidden-state message (miss: word that it will not come, from the "
              "radio or from its sender that could not decide)")
RECORD = {"type": "object", "additionalProperties": True}
STATUS_PROPS = {"ep": INT, "t": INT, "run_tick": INT, "elratio": NUM, "block_coll": INT,
                "robot_coll": INT, "pos": {"type": "array", "items": INTS},
                "alive": {"type": "array", "items": BOOL}, "timeouts": INTS, "bad": INT,
                "late": INT, "heard_links": INT, "vtime": NUM, "wall": NUM}
RSTATUS_PROPS = {"robot": INT, "ep": INT, "msgs_in": INT, "msgs_out": INT, "bytes_in": INT,
                 "bytes_out": INT, "latency_ms": NUM, "compute_ms": NUM, "wait_ms": NUM,
                 "attn": NUMS, "attn_t": INT}


def _record(props: dict[str, Any], title: str, required: tuple[str, ...] = ()) -> dict[str, Any]:
    out = _obj(props, title, closed=False)
    out["required"] = list(required)
    return out


SCHEMAS: dict[str, dict[str, Any]] = {
    "obs": _obj({**HEAD, "y": INT, "x": INT, "patch": INTS, "reward": NUM, "done": BOOL,
                 "budget_ms": NUM}, "swarm observation", optional=BUCKET),
    "traj": TRAJ,
    "bundle": _obj({**HEAD, "senders": INTS, "sizes": INTS,
                    "succ": {"type": ["array", "null"], "items": {"type": "integer"}}},
                   "swarm bundle: whose trajectory messages a robot heard (their contents, "
                   "byte for byte, are on the senders' traj channels); succ: the robots it "
                   "sends its hidden-state message to itself (the radio's fast lane), or null"),
    "hidden": HIDDEN,
    "radio_hidden": HIDDEN,
    "direct": _obj({**HEAD, "kind": {"enum": ["traj", "hidden"]}, "queue_ms": NUM, "size": INT},
                   "swarm direct delivery: a robot's stamped message (queue_ms -1: its "
                   "bandwidth cap dropped it)"),
    "action": _obj({**HEAD, "action": INT, "planning_ms": NUM}, "swarm action",
                   optional=BUCKET | {"heard": INTS}),
    "status": _record(STATUS_PROPS, "swarm world status", ("ep", "t", "run_tick", "elratio")),
    "rstatus": _record(RSTATUS_PROPS, "swarm robot status", ("robot",)),
    "result": _record({"run_id": {"type": "string"}}, "swarm run result"),
    "end": _record({"run_id": {"type": "string"}}, "swarm end of run", ("run_id",)),
    "control": _record({"stop": BOOL}, "swarm control"),
    "lstatus": _record({"version": INT}, "swarm learner status"),
    "weights": _obj({"policy": {"type": "string"}, "version": INT, "origin": INT, "model": RECORD,
                     "shapes": {"type": "object", "additionalProperties": INTS}},
                    "swarm weights (tensor shapes only: the data is on the msgpack channel)"),
    "rollout": _obj({"ep": INT, "robot": INT, "actions": INTS,
                     "heard": {"type": "array", "items": INTS},  # (each tick's ids)
                     "chain_ok": {"type": "array", "items": BOOL}, "logp": NUMS,
                     "last_reward": NUMS, "version": INTS}, "swarm robot episode record"),
    "episode": _obj({"ep": INT, "reward": {"type": "array", "items": NUMS},
                     "acted": {"type": "array", "items": {"type": "array", "items": BOOL}},
                     "metrics": {"type": "object", "additionalProperties": NUM}},
                    "swarm world episode record"),
    "worker_episodes": _obj({"ep": INT, "seed": INT, "version": INT,
                             "actions": {"type": "array", "items": INTS},
                             "metrics": {"type": "object", "additionalProperties": NUM}},
                            "swarm worker episode (arrays on the msgpack channel)"),
}
GENERIC = _record({}, "swarm message without a JSON form (see the msgpack channel)")
RECORD_KINDS = {"status": m.K_STATUS, "rstatus": m.K_RSTATUS, "result": m.K_RESULT,
                "end": m.K_RESULT, "control": m.K_CONTROL, "lstatus": m.K_LSTATUS}


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def _traj(t: m.Traj, cells: int) -> dict[str, Any]:
    return {"ep": t.ep, "t": t.t, "robot": t.robot, "y": t.y, "x": t.x,
            "visited": _b64(t.visited), "visited_cells": int(t.visited_bits(cells).sum()),
            "recent": list(t.recent), "patch": list(t.patch)}


def _hidden(h: m.Hidden) -> dict[str, Any]:
    return {"ep": h.ep, "t": h.t, "robot": h.robot, "action": h.action, "miss": h.is_miss,
            "state": h.vector().tolist()}


def safe(obj: Any, depth: int = 0) -> Any:
    """Any decoded msgpack value as JSON: bytes -> base64, map keys -> str, NaN/inf -> None."""
    if depth > 32:
        raise m.BadMessage("record nested too deeply")
    if isinstance(obj, dict):
        return {str(k): safe(v, depth + 1) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [safe(v, depth + 1) for v in obj]
    if isinstance(obj, bytes):
        return _b64(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def to_json(kind: str, payload: bytes, cfg: WorldConfig) -> dict[str, Any]:
    """The validated JSON form of a payload on a key of `kind` (see `Keys.kind_of`)."""
    if kind == "obs":
        o = m.Obs.unpack(payload, cfg)
        return {"ep": o.ep, "t": o.t, "robot": o.robot, "y": o.y, "x": o.x,
                "patch": list(o.patch), "reward": o.reward, "done": o.done,
                "budget_ms": o.budget_ms} | ({"bucket": list(o.bucket)} if o.bucket else {})
    if kind == "traj":
        return _traj(m.Traj.unpack(payload, cfg), cfg.cells)
    if kind == "bundle":
        b = m.Bundle.unpack(payload, cfg)
        return {"ep": b.ep, "t": b.t, "robot": b.robot,
                "senders": [tr.robot for tr in m.Traj.unpack_many(b.trajs, cfg, b.ep, b.t)],
                "sizes": [len(p) for p in b.trajs], "succ": b.succ}
    if kind == "direct":
        from swarm.net.direct import carried

        st = m.Stamped.unpack(payload, cfg)
        carried(st, cfg)
        return {"ep": st.ep, "t": st.t, "robot": st.robot, "queue_ms": st.queue_ms,
                "kind": "traj" if st.kind == m.K_TRAJ else "hidden", "size": len(st.payload)}
    if kind in ("hidden", "radio_hidden"):
        return _hidden(m.Hidden.unpack(payload, cfg))
    if kind == "action":
        a = m.Action.unpack(payload, cfg)
        return {"ep": a.ep, "t": a.t, "robot": a.robot, "action": a.action,
                "planning_ms": a.planning_ms} | ({"bucket": list(a.bucket)} if a.bucket else {}) | (
                    {"heard": np.unpackbits(np.frombuffer(a.heard, dtype=np.uint8),
                                            count=cfg.n_robots).astype(int).tolist()}
                    if a.heard else {})
    if kind in RECORD_KINDS:
        rec = m.unpack_record(payload, RECORD_KINDS[kind])
        if kind == "rstatus":
            check_robot_status(rec, cfg.n_robots, cfg.horizon)
        return safe(rec)
    if kind == "weights":
        w = learning.Weights.unpack(payload)
        return {"policy": w.policy, "version": w.version, "origin": w.origin,
                "model": safe(w.model),
                "shapes": {k: list(a.shape) for k, a in w.tensors.items()}}
    if kind == "rollout":
        r = learning.RobotRollout.unpack(payload, cfg)
        return {"ep": r.ep, "robot": r.robot, "actions": [t.action for t in r.ticks],
                "heard": [np.flatnonzero(learning.heard_of(t.heard, cfg.n_robots)).tolist()
                          for t in r.ticks], "chain_ok": [t.chain_ok for t in r.ticks],
                "logp": [t.logp for t in r.ticks], "last_reward": [t.last_reward for t in r.ticks],
                "version": [t.version for t in r.ticks]}
    if kind == "episode":
        e = learning.EpisodeRecord.unpack(payload, cfg)
        return {"ep": e.ep, "reward": np.asarray(e.reward, float).tolist(),
                "acted": e.acted.tolist(), "metrics": e.metrics}
    if kind == "worker_episodes":
        w2 = learning.EpisodeRollout.unpack(payload, cfg)
        return {"ep": w2.ep, "seed": w2.seed, "version": w2.version,
                "actions": w2.actions.tolist(), "metrics": w2.metrics}
    raise m.BadMessage(f"no JSON form for kind {kind!r}")
