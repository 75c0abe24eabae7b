"""The world's statuses as the supervisor applies them: in run-tick order, one a tick."""

from __future__ import annotations

from typing import Any

from swarm.net.messages import BadMessage


class StatusOrder:
    """The world sends one status a tick, in order. One before the last applied is a replay
    (BadMessage); one that skips ahead is held until the next goes on from it, and dropped if
    the next goes on from the last applied instead (a forged status far ahead fired every
    planned process fault at once and froze the dashboard: each real status after it was then
    "after" it). A skip is real when the supervisor's inbox overflowed; its next confirms it."""

    def __init__(self) -> None:
        self.tick = 0  # the run tick of the last status applied
        self.held: dict[str, Any] | None = None

    def offer(self, rec: dict[str, Any]) -> tuple[bool, str | None]:
        """Whether to apply status `rec` (its run tick then `tick`), and why a status held
        before it was dropped (None: nothing dropped)."""
        tick, held = rec["run_tick"], self.held
        if tick < self.tick:
            raise BadMessage(f"status of tick {tick} after {self.tick}")
        self.held = None
        dropped = None
        if held is not None and tick == held["run_tick"] + 1:
            self.tick = tick
            return True, None
        if held is not None:
            dropped = (f"status of tick {held['run_tick']} skipped ahead of {self.tick}, and "
                       f"the next did not follow it")
        if tick <= self.tick + 1:
            self.tick = tick
            return True, dropped
        self.held = rec
        return False, dropped

    def end(self, ticks: int | None) -> tuple[dict[str, Any] | None, str | None]:
        """At the world's result (`ticks` played): a status still held is the last tick's
        (returned, to apply) if the run played that far; else why it was dropped."""
        held, self.held = self.held, None
        if held is None:
            return None, None
        if held["run_tick"] == ticks:
            self.tick = held["run_tick"]
            return held, None
        return None, (f"status of tick {held['run_tick']} skipped ahead of {self.tick}, and "
                      f"none followed it")


def in_order(statuses: list[tuple[int, dict[str, Any]]]) -> list[tuple[int, dict[str, Any]]]:
    """Of (index, status) pairs in the order they came, those a supervisor reading them so
    takes (`swarm replay --verify` of a recording that holds a stray): a replay of a passed
    tick and one that skipped ahead with no status following it are left out; one held at the
    end is kept (the last tick's, or a stray past the run, which nothing reads)."""
    order, out, held = StatusOrder(), [], None
    for idx, rec in statuses:
        if not isinstance(rec.get("run_tick"), int):
            continue
        try:
            apply, _ = order.offer(rec)
        except BadMessage:
            continue
        if apply and held is not None and rec["run_tick"] == held[1]["run_tick"] + 1:
            out.append(held)
        if apply:
            out.append((idx, rec))
        held = None if apply else (idx, rec)
    return out + ([held] if held is not None else [])
