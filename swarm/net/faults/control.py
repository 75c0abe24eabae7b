"""Live changes of a run (SPEC section 5): a control record of `swarm/<run>/control` (`swarm
fault`'s link- and process-fault changes, a stop and why) is checked whole by `check_control`;
`FaultSchedule` applies each link-fault change at its tick onto the table in force
(`changed_table`); at most MAX_PENDING wait, in the world and in the supervisor alike.
"""

from __future__ import annotations

import heapq
import logging
from dataclasses import dataclass
from typing import Any

from swarm.net.faults import (
    PROCESS_KINDS,
    FaultPlan,
    ProcessFault,
    cap_keys,
    parse_process,
    plan_from_table,
)
from world.config import ConfigError

log = logging.getLogger("swarm.faults")

MAX_PENDING = 64  # live changes a run holds waiting for their tick; more are dropped and counted
MAX_LOGGED = 256  # applied link-fault changes a result lists (the rest are counted)
CONTROL_KEYS = ("stop", "why", "faults_table", "replace", "at_tick", "process")


@dataclass(frozen=True)
class Control:
    """A checked record of `swarm/<run>/control` (`swarm fault`, the supervisor's stop)."""

    stop: bool = False
    table: dict[str, Any] | None = None
    """A link-fault change (human units; process-fault keys left out), None: no change."""
    replace: bool = False
    at_tick: int = -1
    """Run tick the change applies from (-1: the next tick)."""
    process: tuple[ProcessFault, ...] = ()
    why: str = "control"  # a stop's: an operator's "control", or Ctrl-C's "interrupt"


def link_table(t: dict[str, Any]) -> dict[str, Any]:
    """A `[faults]` table without its process faults (those belong to the supervisor)."""
    return {k: v for k, v in t.items() if k not in PROCESS_KINDS}


def changed_table(in_force: dict[str, Any], c: Control) -> dict[str, Any]:
    """The link-fault table after live change `c`: merged onto the one in force, or replacing
    it (`--replace`, `--clear`), which keeps the run's fault seed unless the change gives one
    (the seed is the run's draws, not a link fault: a replace dropped it, and the draws went
    back to the run's seed)."""
    assert c.table is not None
    if not c.replace:
        return link_table({**in_force, **c.table})
    seed = {"seed": in_force["seed"]} if "seed" in in_force else {}
    return link_table({**seed, **c.table})


def check_control(rec: dict[str, Any], seed: int, n_robots: int) -> Control:
    """Every field of a control record checked before any is acted on: a one-line ConfigError
    naming the first bad one (the world and the supervisor drop and count the whole record)."""
    unknown = sorted(str(k) for k in rec if k not in CONTROL_KEYS)
    if unknown:
        raise ConfigError(f"unknown control field(s) {', '.join(unknown)[:80]}")
    if "stop" in rec and rec["stop"] is not True:
        raise ConfigError(f"stop must be true, got {rec['stop']!r:.40}")
    if "why" in rec and (rec.get("stop") is not True or rec["why"] != "interrupt"):
        raise ConfigError(f"why must be 'interrupt' beside stop, got {rec['why']!r:.40}")
    if not isinstance(rec.get("replace", False), bool):
        raise ConfigError("replace must be a boolean")
    at = rec.get("at_tick", -1)
    if "at_tick" in rec and not (type(at) is int and 0 <= at < 2**40):
        raise ConfigError(f"at_tick must be a run tick in [0, 2**40), got {at!r:.40}")
    table = rec.get("faults_table")
    if table is not None:
        if not isinstance(table, dict):
            raise ConfigError("faults_table must be a table")
        table = link_table(table)
        plan_from_table(table, seed, n_robots)  # the change alone must fit the run
    texts = rec.get("process", [])
    if not isinstance(texts, list) or len(texts) > MAX_PENDING:
        raise ConfigError(f"process faults must be a list of at most {MAX_PENDING}")
    process = []
    for text in texts:
        kind, _, spec = str(text).partition(":")
        if kind not in PROCESS_KINDS:
            raise ConfigError(f"bad process fault {str(text)[:40]!r}: use KIND:ROBOT[@TICK]")
        process.append(parse_process(kind, spec))
    FaultPlan(process=tuple(process)).check(n_robots)
    return Control(rec.get("stop") is True, table, rec.get("replace", False), at, tuple(process),
                   rec.get("why", "control"))


class FaultSchedule:
    """The link faults of a live run: the table in force and the changes waiting for their
    tick, each merged onto the table in force when it applies (a `replace` replaces it), in
    order of tick, then arrival. A change for a tick already played applies at the next one,
    logged and counted late; at most MAX_PENDING wait."""

    def __init__(self, table: dict[str, Any], seed: int, n_robots: int) -> None:
        self.table, self.seed, self.n_robots = dict(table), seed, n_robots
        self.first = plan_from_table(self.table, seed).to_record()  # the plan the run began with
        self.pending: list[tuple[int, int, Control]] = []  # heap: (tick due, arrival, change)
        self.arrivals = 0
        self.log: list[dict[str, Any]] = []  # the first MAX_LOGGED changes applied
        self.counts = {"applied": 0, "late": 0, "dropped": 0, "unfit": 0}

    def add(self, c: Control, run_tick: int) -> bool:
        """Queue the change of `c` (`run_tick`: the tick in play, or the next when between
        ticks); False (dropped, counted) when MAX_PENDING changes wait already."""
        if len(self.pending) >= MAX_PENDING:
            self.counts["dropped"] += 1
            return False
        self.arrivals += 1
        heapq.heappush(self.pending, (max(c.at_tick, run_tick), self.arrivals, c))
        return True

    def due(self, run_tick: int) -> FaultPlan | None:
        """The new plan if a change applies from run tick `run_tick` (the table moves on with
        it), else None."""
        plan = None
        while self.pending and self.pending[0][0] <= run_tick:
            c = heapq.heappop(self.pending)[2]
            table = changed_table(self.table, c)
            try:
                merged = plan_from_table(table, self.seed, self.n_robots)
                if cap_keys(c.table) and not merged.capped:  # (`swarm fault` knows not the cap)
                    raise ConfigError(f"{cap_keys(c.table)[0]} says what a bandwidth cap does; "
                                      "there is no cap in force")
            except ConfigError as exc:  # fit alone, but not merged onto the table in force
                self.counts["unfit"] += 1
                log.warning("fault change dropped at run tick %d: %s", run_tick, exc)
                continue
            self.table, plan = table, merged
            self.counts["applied"] += 1
            if 0 <= c.at_tick < run_tick:
                self.counts["late"] += 1
                log.warning("fault change for run tick %d came late: applied from tick %d",
                            c.at_tick, run_tick)
            if len(self.log) < MAX_LOGGED:
                self.log.append({"tick": run_tick, "at_tick": c.at_tick, "faults": plan.describe()})
        return plan

    def summary(self) -> dict[str, Any]:
        """The result's `fault_changes`: each change applied (its tick, the tick asked for, the
        faults then in force), the counts, and the changes still waiting at the end."""
        return {**self.counts, "changes": list(self.log),
                "pending": sorted([t, c.at_tick] for t, _, c in self.pending)}
