"""Fault models of the radio layer (SPEC section 5), seeded and per run, per robot or per link.

A `FaultPlan` holds a default `LinkFault` (latency + jitter, loss, a bandwidth cap that queues,
drops or expires), overrides per sender and per (sender -> receiver) link, partitions and
process faults (crash, hang, restart of a robot at a run tick). Per-message decisions that do
not depend on wall-clock time (loss, partition, latency draw) are pure functions of the noise
keyed by (fault seed, episode, tick, sender, receiver, kind), so the batched trainer applies
exactly the drops the swarm's radio makes (`delivery_mask`). With every fault at zero nothing
is dropped or delayed. Live changes are `swarm.net.faults.control`'s.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from world.config import ConfigError, check_seed
from world.noise import uniform

log = logging.getLogger("swarm.faults")
STREAM_LOSS, STREAM_JITTER = 11, 12
KIND_TRAJ, KIND_HIDDEN = 0, 1
OVERFLOWS = ("queue", "drop", "expire")  # what a bandwidth cap does with a message over it


@dataclass(frozen=True)
class LinkFault:
    """Faults of one directed link (or of every link of a sender, or the default)."""

    latency_ms: float = 0.0
    """Fixed one-way delay."""
    jitter_ms: float = 0.0
    """Extra delay drawn uniformly in [0, jitter_ms) per message."""
    loss: float = 0.0
    """Probability that a message is lost."""
    bandwidth: float = 0.0
    """Cap in bytes/s of the sender's outgoing radio traffic on this link (0: unlimited)."""
    burst: float = 0.0
    """Token-bucket depth in bytes (0: one second's worth of `bandwidth`)."""
    overflow: str = "queue"
    """What the token bucket does with a message that exceeds the cap: `queue` it (it waits for
    tokens), `drop` it, or `expire` it: queue it unless it would leave the queue after its
    tick's deadline, when it is discarded unsent and costs no tokens (a sender that stays
    silent when its link cannot carry the message in time; DDS's LIFESPAN at the writer)."""
    compute_ms: float = 0.0
    """Virtual clock: the sender's modelled compute time, from a tick's start to its sends
    (a sender's property: set it for all robots or per robot)."""

    def __post_init__(self) -> None:
        for name in ("latency_ms", "jitter_ms", "compute_ms"):
            if not 0 <= getattr(self, name) <= MAX_MS:  # also NaN
                raise ConfigError(f"{name} must lie in [0, {MAX_MS:g}], got {getattr(self, name)}")
        for name in ("bandwidth", "burst"):
            if not 0 <= getattr(self, name) <= 1e12:
                raise ConfigError(f"{name} must lie in [0, 1e12], got {getattr(self, name)}")
        if not 0.0 <= self.loss <= 1.0:
            raise ConfigError(f"loss must be in [0, 1], got {self.loss}")
        if self.overflow not in OVERFLOWS:
            raise ConfigError(f"overflow must be one of {', '.join(OVERFLOWS)}, "
                              f"got {self.overflow!r}")

    @property
    def zero(self) -> bool:
        return (self.latency_ms == 0 and self.jitter_ms == 0 and self.loss == 0
                and self.bandwidth == 0 and self.compute_ms == 0)


@dataclass(frozen=True)
class ProcessFault:
    """`kind` (crash, hang or restart) of robot `robot` when the run reaches tick `tick`."""

    kind: str
    robot: int
    tick: int


@dataclass(frozen=True)
class FaultPlan:
    default: LinkFault = field(default_factory=LinkFault)
    per_robot: dict[int, LinkFault] = field(default_factory=dict)
    per_link: dict[tuple[int, int], LinkFault] = field(default_factory=dict)
    partition: tuple[tuple[int, ...], ...] = ()
    process: tuple[ProcessFault, ...] = ()
    seed: int = 0

    def check(self, n_robots: int) -> FaultPlan:
        """Every robot id the plan names exists in a team of `n_robots`; a one-line ConfigError
        otherwise (checked before a run starts, and on every live change)."""
        ids = [*self.per_robot, *(x for pair in self.per_link for x in pair),
               *(r for g in self.partition for r in g), *(p.robot for p in self.process)]
        bad = sorted({r for r in ids if not 0 <= r < n_robots})
        shown = ", ".join(map(str, bad[:5])) + f" and {len(bad) - 5} more" * (len(bad) > 5)
        if bad:
            raise ConfigError(f"faults name robot(s) {shown} but the team has robots "
                              f"0..{n_robots - 1}")
        return self

    def link(self, sender: int, receiver: int) -> LinkFault:
        return self.per_link.get((sender, receiver), self.per_robot.get(sender, self.default))

    @property
    def zero(self) -> bool:
        return (self.default.zero and all(f.zero for f in self.per_robot.values())
                and all(f.zero for f in self.per_link.values()) and not self.partition)

    @property
    def capped(self) -> bool:
        """Whether any sender has a bandwidth cap (what `overflow` and `burst` are about)."""
        return any(f.bandwidth for f in (self.default, *self.per_robot.values()))

    def group_of(self, n: int) -> np.ndarray:
        """Partition group id per robot [n]; robots in no listed group form one more group."""
        g = np.full(n, len(self.partition), dtype=np.int64)
        for k, members in enumerate(self.partition):
            for r in members:
                if 0 <= r < n:
                    g[r] = k
        return g

    def panel(self) -> list[str]:
        """`describe()` as a world status carries it (what every reader of one accepts): at
        most PANEL_LINES lines of at most PANEL_WIDTH characters, the rest counted in the last
        (a partition of 128 robots, or 64 robots' own faults, dropped every status)."""
        lines = [x if len(x) <= PANEL_WIDTH else x[:PANEL_WIDTH - 3] + "..."
                 for x in self.describe()]
        if len(lines) > PANEL_LINES:
            lines = [*lines[:PANEL_LINES - 1], f"... {len(lines) - PANEL_LINES + 1} more"]
        return lines

    def describe(self) -> list[str]:
        """Short human-readable lines of the faults in force (dashboard, logs)."""
        out = []

        def fmt(f: LinkFault) -> str:
            parts = []
            if f.latency_ms or f.jitter_ms:
                parts.append(f"latency {f.latency_ms:g}+{f.jitter_ms:g}ms")
            if f.loss:
                parts.append(f"loss {f.loss:g}")
            if f.bandwidth:
                parts.append(f"bw {f.bandwidth:g}B/s {f.overflow}")
            if f.compute_ms:
                parts.append(f"compute {f.compute_ms:g}ms")
            return " ".join(parts)

        if not self.default.zero:
            out.append("all: " + fmt(self.default))
        out += [f"robot {r}: {fmt(f)}" for r, f in sorted(self.per_robot.items())]
        out += [f"link {a}->{b}: {fmt(f)}" for (a, b), f in sorted(self.per_link.items())]
        if self.partition:
            out.append("partition " + "/".join(",".join(map(str, g)) for g in self.partition))
        out += [f"{p.kind} {p.robot}" + (f"@{p.tick}" if p.tick >= 0 else " at once")
                for p in self.process]
        return out

    def to_record(self) -> dict[str, Any]:
        """A msgpack/JSON-safe form (live `swarm fault` updates, results)."""
        lf = lambda f: {k: getattr(f, k) for k in LinkFault.__dataclass_fields__}  # noqa: E731
        return {
            "default": lf(self.default),
            "per_robot": {str(r): lf(f) for r, f in self.per_robot.items()},
            "per_link": {f"{a}-{b}": lf(f) for (a, b), f in self.per_link.items()},
            "partition": [list(g) for g in self.partition],
            "process": [[p.kind, p.robot, p.tick] for p in self.process], "seed": self.seed,
        }

    @classmethod
    def from_record(cls, rec: dict[str, Any]) -> FaultPlan:
        try:
            lf = lambda d: LinkFault(**d)  # noqa: E731
            return cls(
                default=lf(rec.get("default", {})),
                per_robot={int(r): lf(d) for r, d in rec.get("per_robot", {}).items()},
                per_link={tuple(int(x) for x in k.split("-")): lf(d)  # type: ignore[misc]
                          for k, d in rec.get("per_link", {}).items()},
                partition=tuple(tuple(int(r) for r in g) for g in rec.get("partition", [])),
                process=tuple(ProcessFault(str(k), int(r), int(t))
                              for k, r, t in rec.get("process", [])), seed=int(rec.get("seed", 0)),
            )
        except (TypeError, ValueError, AttributeError) as exc:
            raise ConfigError(f"bad fault record: {exc}") from None


# --------------------------------------------------------------------- parsing of CLI values

PANEL_LINES, PANEL_WIDTH = 64, 240  # a status's fault lines (`FaultPlan.panel`)
MAX_MS = 3.6e6  # an hour: the longest latency or jitter a plan may hold
MAX_ROBOTS = 100_000  # robot ids a plan may name (bounds a hostile partition list)
_UNITS_TIME = {"us": 1e-3, "ms": 1.0, "s": 1000.0, "": 1.0}
_UNITS_RATE = {"b": 1.0, "kb": 1e3, "mb": 1e6, "kib": 1024.0, "mib": 1024.0 ** 2}


def parse_duration_ms(text: str) -> float:
    """`50ms`, `0.2s`, `300` (ms) -> milliseconds."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(us|ms|s|)\s*", str(text).lower())
    if not m:
        why = "must be >= 0" if str(text).strip().startswith("-") else "use e.g. 50ms or 0.2s"
        raise ConfigError(f"bad duration {text!r}: {why}")
    return float(m.group(1)) * _UNITS_TIME[m.group(2)]


def parse_rate(text: str) -> float:
    """`2kB/s`, `500B/s`, `1MB/s`, `2000` (bytes/s) -> bytes per second; `none` -> 0, no cap
    (a sweep's baseline point). The unit is bytes and says so with a capital B: `2kb`
    (kilobits, to most readers) is refused, not guessed."""
    if str(text).strip().lower() == "none":
        return 0.0
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([kKmM]i?)?(B|b)?(?:/s)?\s*", str(text))
    if not m or (m.group(2) and not m.group(3)):
        why = "must be above 0 (none: no cap)" if str(text).strip().startswith("-") else \
            "use e.g. 2kB/s, or none"
        raise ConfigError(f"bad bandwidth {text!r}: {why}")
    if m.group(3) == "b":
        raise ConfigError(f"bad bandwidth {text!r}: the unit is bytes, written B (e.g. 2kB/s); "
                          "b would be bits")
    return float(m.group(1)) * _UNITS_RATE[(m.group(2) or "").lower() + "b"]


def parse_ids(text: str) -> tuple[int, ...]:
    """`0-4` or `0,2,5` or `1-3,7` -> robot ids."""
    out: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m:
            raise ConfigError(f"bad robot list {text!r}: use e.g. 0-4 or 0,2,5")
        lo, hi = int(m.group(1)), int(m.group(2) or m.group(1))
        if hi < lo or hi >= MAX_ROBOTS:
            raise ConfigError(f"bad robot range {part!r} (ids lie in 0..{MAX_ROBOTS - 1})")
        out += range(lo, hi + 1)
    return tuple(out)


def parse_partition(text: str) -> tuple[tuple[int, ...], ...]:
    """`0-4/5-9` -> ((0..4), (5..9)); a robot may be in one group only, and the robots in no
    group form one more (`0` on 4 robots is `0/1-3`); `""` is no partition."""
    parts = [g.strip() for g in str(text).split("/")]
    if parts != [""] and "" in parts:
        raise ConfigError(f"bad partition {text!r}: an empty group (use e.g. 0-4/5-9)")
    groups = tuple(parse_ids(g) for g in parts if g)
    seen: set[int] = set()
    for g in groups:
        if seen & set(g):
            raise ConfigError(f"partition {text!r} puts a robot in two groups")
        seen |= set(g)
    return groups


def parse_process(kind: str, text: str, at_once: bool = True) -> ProcessFault:
    """`3@20` -> robot 3 at run tick 20; `3` -> robot 3 at once (tick -1), if `at_once` (a live
    change: a run's plan names its tick)."""
    m = re.fullmatch(r"\s*(\d{1,9})\s*(?:@\s*(\d{1,12}))?\s*", str(text))
    if not m or not (at_once or m.group(2)):
        raise ConfigError(f"bad --{kind} {text!r}: use ROBOT@TICK, e.g. 3@20")
    return ProcessFault(kind, int(m.group(1)), int(m.group(2)) if m.group(2) else -1)


LINK_KEYS = ("latency", "jitter", "loss", "bandwidth", "burst", "overflow", "compute")
"""The keys of one link's faults in a `[faults]` table (human units)."""


def _number(v: Any, name: str) -> float:
    """A fault's number (a float or its text); a bool is refused (`loss = true` became 1.0)."""
    try:
        return float(v if not isinstance(v, bool) else "bool")
    except (TypeError, ValueError):
        raise ConfigError(f"bad {name} {v!r}: a number is expected") from None


SENDER_KEYS = ("bandwidth", "burst", "overflow", "compute")
"""Fault keys of a sender's radio, not of one link: set per run or per robot."""


def link_fault_from(d: dict[str, Any], base: LinkFault | None = None) -> LinkFault:
    """A LinkFault from a TOML/CLI mapping with human units (latency = "50ms", ...)."""
    if not isinstance(d, dict):
        raise ConfigError(f"bad faults table: {d!r:.40} is not a table of link faults")
    base, known = base or LinkFault(), set(LINK_KEYS)
    unknown = set(d) - known
    if unknown:
        raise ConfigError(f"unknown fault key(s) {', '.join(sorted(unknown))}; known: "
                          f"{', '.join(sorted(known))}")
    ch: dict[str, Any] = {}
    for key in ("latency", "jitter", "compute"):
        if key in d:
            ch[f"{key}_ms"] = parse_duration_ms(d[key])
    if "loss" in d:
        ch["loss"] = _number(d["loss"], "loss")
    if "bandwidth" in d:
        ch["bandwidth"] = parse_rate(d["bandwidth"])
        if ch["bandwidth"] == 0 and str(d["bandwidth"]).strip().lower() != "none":
            # (0 meant "no cap": a user asking for no bandwidth got all of it)
            raise ConfigError(f"bad bandwidth {d['bandwidth']!r}: a cap must be above 0 B/s "
                              "(no cap: leave it out, or write none)")
    if "burst" in d:
        ch["burst"] = _number(d["burst"], "burst")
    if "overflow" in d:
        ch["overflow"] = str(d["overflow"])
    return replace(base, **ch)


def cap_keys(table: Any) -> list[str]:
    """Of `overflow` and `burst` (what a bandwidth cap does), those a (nested) faults table
    sets anywhere, per robot too: with no cap in force they change nothing, so a run or a live
    change that gives one is refused rather than run as if without it."""
    def has(t: Any, key: str) -> bool:
        return isinstance(t, dict) and (key in t or any(has(v, key) for v in t.values()))
    return [k for k in ("overflow", "burst") if has(table, k)]


def plan_from_table(t: dict[str, Any], seed: int = 0, n_robots: int | None = None,
                    at_once: bool = False) -> FaultPlan:
    """`[faults]` of an experiment file: latency, jitter, loss, bandwidth, overflow, partition,
    crash/hang/restart lists, `[faults.robot.K]` and `[faults.link."A-B"]` overrides. Anything
    malformed (also from a live `swarm fault` message) is a one-line ConfigError; with
    `n_robots`, so is a robot id outside the team. A process fault names its tick unless
    `at_once` (a live change's may strike at once)."""
    if not isinstance(t, dict):
        raise ConfigError("faults must be a table")
    try:
        plan = _plan(dict(t), seed, at_once)
    except (TypeError, ValueError, AttributeError, OverflowError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"bad faults table: {exc}") from None
    return plan if n_robots is None else plan.check(n_robots)


def _plan(t: dict[str, Any], seed: int, at_once: bool) -> FaultPlan:
    per_robot_t, per_link_t = t.pop("robot", {}), t.pop("link", {})
    if not isinstance(per_robot_t, dict) or not isinstance(per_link_t, dict):
        raise ConfigError("bad faults table: robot and link are tables ([faults.robot.K] ...)")
    partition = parse_partition(t.pop("partition")) if "partition" in t else ()
    process: list[ProcessFault] = []
    for kind in ("crash", "hang", "restart"):
        items = t.pop(kind, [])
        items = [items] if isinstance(items, str) else items
        if not isinstance(items, list):  # (`crash = 5`: "'int' object is not iterable")
            raise ConfigError(f"bad {kind} {items!r:.40}: a list of ROBOT@TICK, e.g. "
                              f'{kind} = ["1@20"]')
        process += [parse_process(kind, x, at_once) for x in items]
    fseed = t.pop("seed", seed)
    check_seed(fseed, "faults seed")
    default = link_fault_from(t)
    per_robot = {}
    for k, v in per_robot_t.items():  # ("x": int()'s own words; "1_0": robot 10; "00": "0")
        if not (str(k).isdigit() and str(int(k)) == str(k)):
            raise ConfigError(f"bad robot {str(k)[:20]!r} in [faults.robot]: a robot id, e.g. "
                              "[faults.robot.3]")
        per_robot[int(k)] = link_fault_from(v, default)
    per_link = {}
    for k, v in per_link_t.items():
        a, sep, b = str(k).partition("-")
        if not sep or not a.isdigit() or not b.isdigit():
            raise ConfigError(f"bad link {k!r}: use \"SENDER-RECEIVER\"")
        if int(a) == int(b):
            raise ConfigError(f"bad link {k!r}: a robot's link to itself (its own message is "
                              "always delivered)")
        owned = [key for key in SENDER_KEYS if isinstance(v, dict) and key in v]
        if owned:  # (accepted and shown, then ignored: the radio reads them per sender)
            raise ConfigError(f"bad link {k!r}: {', '.join(owned)} belong(s) to the sender (one "
                              f"radio, one token bucket, one compute time for all its links): "
                              f"set it in [faults.robot.{a}]")
        per_link[(int(a), int(b))] = link_fault_from(v, default)
    return FaultPlan(default, per_robot, per_link, partition, tuple(process), fseed)


# --------------------------------------------------------------------- per-message decisions


def delivery_mask(plan: FaultPlan, episodes: np.ndarray, tick: int, n: int,
                  kind: int = KIND_TRAJ, budget_ms: float | None = None,
                  links: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                  partition: bool = True) -> np.ndarray:
    """[G, N, N] bool: does j's message reach i (loss, partition, and latency within budget)?

    The same decisions the swarm's radio makes for each (episode, tick, sender, receiver); the
    diagonal (a robot's own message) is always delivered. Bandwidth queueing depends on wall
    time and message sizes and is applied by the radio only.
    """
    episodes = np.asarray(episodes, dtype=np.int64)
    g = len(episodes)
    ok = np.ones((g, n, n), dtype=bool)
    if plan.zero:
        return ok
    loss, lat, jit = links if links is not None else link_arrays(plan, n)
    recv, send = np.arange(n)[:, None], np.arange(n)[None, :]
    u = uniform(plan.seed, episodes[:, None, None], tick, send * 1000 + recv, 1,
                stream=STREAM_LOSS + 100 * kind)[..., 0]
    ok &= ~(u < loss.T[None])  # loss[j, i] is the link j -> i; ok[g, i, j]
    if plan.partition and partition:
        grp = plan.group_of(n)
        ok &= (grp[:, None] == grp[None, :])[None]
    if budget_ms is not None:
        ok &= (delay_ms(plan, episodes, tick, n, kind, lat, jit) <= budget_ms)
    idx = np.arange(n)
    ok[:, idx, idx] = True
    return ok


def link_arrays(plan: FaultPlan, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-link loss, latency and jitter as [sender, receiver] arrays."""
    loss, lat, jit = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
    for j in range(n):
        for i in range(n):
            f = plan.link(j, i)
            loss[j, i], lat[j, i], jit[j, i] = f.loss, f.latency_ms, f.jitter_ms
    return loss, lat, jit


def delay_ms(plan: FaultPlan, episodes: np.ndarray, tick: int, n: int, kind: int,
             lat: np.ndarray | None = None, jit: np.ndarray | None = None) -> np.ndarray:
    """[G, N(receiver), N(sender)] one-way delay of each message, latency + jitter draw."""
    if lat is None or jit is None:
        _, lat, jit = link_arrays(plan, n)
    recv, send = np.arange(n)[:, None], np.arange(n)[None, :]
    u = uniform(plan.seed, np.asarray(episodes)[:, None, None], tick, send * 1000 + recv, 1,
                stream=STREAM_JITTER + 100 * kind)[..., 0]
    return lat.T[None] + jit.T[None] * u


PROCESS_KINDS = ("crash", "hang", "restart")
