"""The records the world, the robots and the supervisor put (msgpack maps: statuses, results,
robot statuses), checked field by field before any reader uses them (`swarm.net.messages` has
the wire messages and their helpers)."""

from __future__ import annotations

import functools
import itertools
import re
from typing import Any

import numpy as np

from swarm.net.direct import MAX_RESTARTS
from swarm.net.faults import PANEL_LINES, PANEL_WIDTH
from swarm.net.messages import BIG, MAX_MS, BadMessage, _float, _int, _ints
from world.config import WorldConfig

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
    if not isinstance(faults, list) or len(faults) > PANEL_LINES or \
            not all(isinstance(f, str) and len(f) <= PANEL_WIDTH for f in faults):
        raise BadMessage(f"status faults must be at most {PANEL_LINES} lines of text")
    if not isinstance(radio, dict) or len(radio) > 64 or not all(
            isinstance(k, str) and (isinstance(v, dict) and len(v) <= 16  # (by_kind)
                                    or isinstance(v, list)  # (reported, restarted)
                                    and len(v) <= (MAX_RESTARTS + 1) * n
                                    or type(v) in (int, float) and 0 <= v <= 1e18)
            for k, v in radio.items()):
        raise BadMessage("status radio must be at most 64 counts (numbers >= 0) by name")
    if not isinstance(links, dict) or len(links) > n * n:
        raise BadMessage(f"status links must hold at most {n * n} links")
    if links and not _good_links(links, n):  # (the slow walk only to name the bad link)
        for k, v in links.items():
            if not _is_link_key(k, n) or not isinstance(v, list) or len(v) != 4:
                raise BadMessage(f'status links: {str(k)[:20]!r} is no "SENDER-RECEIVER" of 4 '
                                 "counts")
            _ints(v, f"status links {k}", 0, BIG)


LINK_KEYS_HELD = 256
"""Teams up to this size check link keys against a set of every key (65,536 strings, ~4 MB);
larger ones parse each key (a set for 1,000 robots would be 10^6 strings, ~65 MB)."""


@functools.lru_cache(maxsize=8)
def _link_keys(n: int) -> frozenset[str]:
    """Every "SENDER-RECEIVER" key a team of n writes (as `faulted_links` spells them)."""
    return frozenset(f"{j}-{i}" for j in range(n) for i in range(n))


def _is_link_key(k: Any, n: int) -> bool:
    """Whether `k` is "j-i" for robots j, i < n, spelt as `faulted_links` does (no sign, no
    leading zero)."""
    if n <= LINK_KEYS_HELD:
        return isinstance(k, str) and k in _link_keys(n)
    return _parsed_keys({k: None}, n)


_KEY = r"(?:0|[1-9][0-9]{0,9})-(?:0|[1-9][0-9]{0,9})"
_KEYS = re.compile(f"{_KEY}(?:\n{_KEY})*+")  # (possessive: no backtracking stack)


def _parsed_keys(links: dict[Any, Any], n: int) -> bool:
    """Whether every key is "j-i" for robots j, i < n, in one regex match and C-level int
    parsing (what `_is_link_key` asks of one key past LINK_KEYS_HELD robots): 62 ms for the
    89,700 links of 300 robots, against 367 ms key by key (a set lookup: 52 ms for 256 robots'
    65,280)."""
    try:
        joined = "\n".join(links)
    except TypeError:  # (a key not text)
        return False
    if joined.count("\n") != len(links) - 1 or not _KEYS.fullmatch(joined):  # (a key with \n)
        return False
    return max(map(int, joined.replace("-", "\n").split("\n"))) < n


def _good_links(links: dict[Any, Any], n: int) -> bool:
    """Every key a link of the team and every value 4 ints in [0, BIG], in builtins that run in
    C: a status of 100 robots under loss carries ~9,900 links each tick (18 ms a status in a
    Python loop, read by the supervisor, `swarm replay` and `swarm trace`)."""
    values = links.values()
    keys_ok = links.keys() <= _link_keys(n) if n <= LINK_KEYS_HELD else _parsed_keys(links, n)
    if not keys_ok or set(map(type, values)) != {list} or \
            set(map(len, values)) != {4}:
        return False
    flat = list(itertools.chain.from_iterable(values))
    return set(map(type, flat)) == {int} and 0 <= min(flat) and max(flat) <= BIG


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
