"""What the supervisor samples of its children from /proc: peak RSS and PSS, and CPU seconds
per tick by process kind (startup excluded), for the run's result and `swarm bench swarm`."""

from __future__ import annotations

import math
import os
import subprocess
import time
from typing import Any


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of process `pid` so far (None if it is gone)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def stopped(pid: int) -> bool:
    """Whether process `pid` is stopped (SIGSTOP, SIGTSTP, a debugger): state T or t."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] in ("T", "t")
    except (OSError, IndexError):
        return False


def _kb(path: str, field: str) -> float | None:
    try:
        with open(path) as fh:
            return float(next(int(line.split()[1]) for line in fh if line.startswith(field)))
    except (OSError, StopIteration, ValueError):
        return None


class ProcSampler:
    """Peak memory and CPU of named child processes ("world", "robot3", ...)."""

    def __init__(self) -> None:
        self.rss_mb: dict[str, float] = {}  # peak resident memory per child
        self.pss_mb: dict[str, float] = {}  # peak proportional set size (shared pages split)
        # CPU seconds at a child's first sample after the first tick and at its last one, with
        # the ticks done then
        self.cpu_first: dict[str, tuple[float, int]] = {}
        self.cpu_last: dict[str, tuple[float, int]] = {}
        self._turn = 0  # round robin over the children for PSS
        self._last = -math.inf  # when it last sampled (time.monotonic)

    def sample(self, procs: dict[str, subprocess.Popen | None], ticks_done: int,
               pss_per_call: int = 4, every: float = 0.0) -> None:
        """RSS and CPU of every child; PSS of `pss_per_call` of them in turn (the kernel walks
        a process's page tables for it: for hundreds of robots, every one every call would be
        most of the supervisor's time). Nothing if it sampled less than `every` s ago."""
        if time.monotonic() - self._last < every:
            return
        self._last = time.monotonic()
        names = sorted(n for n in procs if n != "world")
        pss_for = {names[(self._turn + k) % len(names)]
                   for k in range(min(pss_per_call, len(names)))} if names else set()
        pss_for.add("world")  # one process, sampled every call (robots take turns)
        self._turn += pss_per_call
        for name, p in procs.items():
            if p is None or p.poll() is not None:
                continue
            rss = _kb(f"/proc/{p.pid}/status", "VmRSS:")
            if rss is None:
                continue
            self.rss_mb[name] = max(self.rss_mb.get(name, 0.0), rss / 1024)
            pss = _kb(f"/proc/{p.pid}/smaps_rollup", "Pss:") if name in pss_for else None
            if pss is not None:
                self.pss_mb[name] = max(self.pss_mb.get(name, 0.0), pss / 1024)
            cpu = cpu_seconds(p.pid)
            if cpu is not None and ticks_done > 0:
                self.cpu_first.setdefault(name, (cpu, ticks_done))
                self.cpu_last[name] = (cpu, ticks_done)

    def _rate(self, name: str) -> float | None:
        if name not in self.cpu_first:
            return None
        (c0, t0), (c1, t1) = self.cpu_first[name], self.cpu_last[name]
        return 1e3 * (c1 - c0) / (t1 - t0) if t1 > t0 else None

    def summary(self) -> dict[str, Any]:
        """The result's memory and CPU figures (None where nothing was sampled)."""
        def mean(d: dict[str, float]) -> float | None:
            v = [x for k, x in d.items() if k.startswith("robot")]
            return sum(v) / len(v) if v else None

        robots = [r for r in (self._rate(k) for k in self.cpu_last if k.startswith("robot"))
                  if r is not None]
        return {"rss_mb_per_robot": mean(self.rss_mb), "rss_mb_world": self.rss_mb.get("world"),
                "pss_mb_per_robot": mean(self.pss_mb), "pss_mb_world": self.pss_mb.get("world"),
                "cpu_ms_per_tick": {"world": self._rate("world"),
                                    "robots": sum(robots) if robots else None,
                                    "per_robot": sum(robots) / len(robots) if robots else None}}


def process_age() -> float | None:
    """Seconds since this process started (from /proc): `swarm run`'s time to its first tick
    counts from the command, interpreter start and imports included."""
    try:
        with open("/proc/self/stat") as fh:
            start = int(fh.read().rsplit(")", 1)[1].split()[19]) / os.sysconf("SC_CLK_TCK")
        with open("/proc/uptime") as fh:
            return float(fh.read().split()[0]) - start
    except (OSError, IndexError, ValueError):
        return None
