"""Which robots the world observes at a tick: those whose liveliness token is up, less those a
process fault of the run's plan holds down.

On the virtual clock a crash, hang or restart of the plan (`--crash 2@20`, `swarm fault
--restart 2@40`) takes effect at exactly its run tick, whatever the wall clock: the world holds
the robot down from that tick (not observed, its messages unused) and, at a restart's tick,
waits for its token before the tick starts (a fresh process takes a second or two to come up,
while the run plays ~100 ticks a second). The supervisor still delivers the signal or the new
process, when the world's status reaches the tick; so a run with process faults is as much a
function of its seed and fault plan as one without. On the real clock nothing is held: the
faults land when the signals do, as on a real network.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable

import numpy as np

from swarm.net.faults import ProcessFault

log = logging.getLogger("swarm.world")


class Presence:
    """The robots present (`alive`, `live`: the same ids as an array and a set) and those ever
    present, from liveliness tokens and, when `gated`, the plan's process faults."""

    def __init__(self, n_robots: int, process: Iterable[ProcessFault] = (),
                 gated: bool = False, restart_crashed: bool = False) -> None:
        self.alive = np.zeros(n_robots, dtype=bool)
        self.live: set[int] = set()
        self.ever_alive = np.zeros(n_robots, dtype=bool)
        self.tokens: set[int] = set()  # robots whose token is up, held down or not
        self.down: set[int] = set()  # robots a crash or hang of the plan holds down
        self.gated = gated
        self.restart_crashed = restart_crashed  # a crash at t: a restart at t + 1
        self.pending: list[tuple[ProcessFault, bool]] = []  # (fault, queued as the supervisor
        self.add(process)  # queues it: it named its tick), in order of tick

    @property
    def queued(self) -> int:
        """Pending faults that named their tick: the supervisor's queue of signals to send."""
        return sum(timed for _, timed in self.pending)

    def add(self, faults: Iterable[ProcessFault], now: int = 0, limit: int | None = None) -> bool:
        """Process faults for their run tick; a live one without a tick (`swarm fault --crash
        2`) for `now`, the next tick to play (a restart without one released nothing: a robot a
        planned crash held down stayed down for good). False, and nothing added, when more than
        `limit` would then be queued: the supervisor drops (and counts) such a change as a whole
        and never signals it, so the world must not hold its robots down either."""
        faults = list(faults)
        if limit is not None and self.queued + len(faults) > limit:
            return False
        if self.gated:
            due = ((f, True) if f.tick >= 0 else (ProcessFault(f.kind, f.robot, now), False)
                   for f in faults)
            self.pending = sorted([*self.pending, *due], key=lambda e: e[0].tick)
        return True

    def token(self, robot: int, up: bool) -> None:
        """A liveliness event of robot `robot`."""
        (self.tokens.add if up else self.tokens.discard)(robot)
        self._set(robot, up and robot not in self.down)

    def held(self, robot: int) -> bool:
        """Whether a process fault holds `robot` down (its messages change nothing)."""
        return robot in self.down

    def due(self, tick: int) -> list[int]:
        """Apply the faults of run tick `tick`; the robots restarted now whose token is not up
        yet (the world waits for them before the tick starts)."""
        waiting = []
        while self.pending and self.pending[0][0].tick <= tick:
            f = self.pending.pop(0)[0]
            if f.kind in ("crash", "hang"):
                self.down.add(f.robot)
                self._set(f.robot, False)
                if f.kind == "crash":  # its process is being killed: a restart waits for the
                    self.tokens.discard(f.robot)  # new one's token, not the old one's last
                    # moments (a crash and restart of one tick set it alive, then lost it)
                    if self.restart_crashed:  # (the supervisor respawns it at once)
                        self.pending.append((ProcessFault("restart", f.robot, tick + 1), False))
                        self.pending.sort(key=lambda e: e[0].tick)  # (stable: after its tick's)
            elif f.robot in self.down:  # restart: up again from this tick
                self.down.discard(f.robot)
                if f.robot in self.tokens:
                    self._set(f.robot, True)
                else:
                    waiting.append(f.robot)
        return waiting

    def wait_up(self, waiting: list[int], pump: Callable[[float], bool], deadline: float) -> None:
        """Before a tick: handle events (`pump(deadline)`, False once it passed) until the
        robots restarted at it are up; one that is not by `deadline` joins when it comes."""
        while any(r not in self.live for r in waiting) and pump(deadline):
            pass
        for r in (r for r in waiting if r not in self.live):
            log.warning("robot %d, restarted, was not up in time: it joins when it comes", r)

    def _set(self, robot: int, on: bool) -> None:
        self.alive[robot] = on
        (self.live.add if on else self.live.discard)(robot)
        self.ever_alive[robot] |= on
