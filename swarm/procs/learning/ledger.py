"""What a learner knows of the episodes it was sent, kept across a resume: the swarm episodes it
has settled (joined or given up), so that a late record of one is counted late rather than as a
new episode, and each rollout worker's next episode, so that a worker started again goes on
after its last one instead of replaying its seed's maps from 0 (docs/DECISIONS.md, "A resumed
learner settles what its stopped self heard of", "A restarted rollout worker goes on where its
learner has it").

Both are hostile input's targets (an episode number is whatever a record says), so both are
bounded: the settled set forgets its oldest half past FORGET_ABOVE (a watermark keeps them
settled), a checkpoint names the latest SETTLED_KEPT, and at most MAX_WORKERS workers are kept,
each next episode at most BIG."""

from __future__ import annotations

import logging
from collections.abc import Collection
from typing import Any

from swarm.learn.config import MAX_WORKER_ID
from swarm.net.learning import EpisodeRollout
from swarm.net.messages import BIG, BadMessage
from swarm.procs.runconfig import MAX_WORKERS, check_worker_next
from world.config import ConfigError

log = logging.getLogger("swarm.learner")

SETTLED_KEPT = 4096
"""The latest settled swarm episodes a checkpoint names, beside those still joining."""
FORGET_ABOVE = 100_000
"""Settled episodes kept one by one; past it the oldest half goes under the watermark."""


def _episode(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and 0 <= x <= BIG


class Settled:
    """The swarm episodes a learner has joined or given up (`ep in settled`), and the highest
    (`last`, what a lockstep world waits for). Resumed, it starts with those its stopped self
    had settled or was joining (`resume`): a record of one of those is said (`late`)."""

    def __init__(self) -> None:
        self.closed: set[int] = set()
        self.upto = -1  # every episode at or below it is settled (forgotten from `closed`)
        self.last = -1
        self.resumed: set[int] = set()  # those the learner this one resumed had settled
        self.resumed_late = 0  # records of those since (said at the 1st, 2nd, 4th...)

    def __contains__(self, ep: int) -> bool:
        return ep <= self.upto or ep in self.closed

    def add(self, ep: int) -> None:
        self.closed.add(ep)
        self.last = max(self.last, ep)
        if len(self.closed) > FORGET_ABOVE:  # a long run: forget the oldest half
            old = sorted(self.closed)
            half = FORGET_ABOVE // 2
            self.upto = max(self.upto, old[half - 1])
            self.closed = set(old[half:])

    def late(self, ep: int) -> None:
        """A record of settled episode `ep` came (counted late by the learner)."""
        if ep in self.resumed:
            self.resumed_late += 1
            if self.resumed_late & (self.resumed_late - 1) == 0:
                log.warning("learner: a record of episode %d, which the learner this one "
                            "resumed had settled, counted late (%d so far; a world started "
                            "again? give it a --first-episode past the episodes it played)", ep,
                            self.resumed_late)

    def state(self, joining: set[int] | dict[int, Any]) -> dict[str, Any]:
        """For a checkpoint: the latest settled episodes and those still `joining` (lost if
        the learner stops before its next update: a late record of them is late too)."""
        return {"swarm_settled": sorted(self.closed)[-SETTLED_KEPT:] + sorted(joining),
                "swarm_closed_upto": self.upto}

    def resume(self, state: dict[str, Any]) -> None:
        """Settle what a checkpoint's learner `state` names; an entry out of range is dropped (a
        checkpoint from before they were kept has none)."""
        named = state.get("swarm_settled", [])
        self.heard_before(named[:2 * SETTLED_KEPT] if isinstance(named, list) else [])
        upto = state.get("swarm_closed_upto", -1)
        if upto == -1 or _episode(upto):
            self.upto = max(self.upto, upto)

    def heard_before(self, episodes: Collection[Any]) -> None:
        """Settle episodes the learner this one resumed had heard of (its checkpoint's, or its
        journal's after it)."""
        named = {e for e in episodes if _episode(e)}
        self.resumed |= named
        self.closed |= named
        self.last = max(self.closed, default=-1)


class Workers:
    """Each rollout worker's next episode (`next`: worker id -> episode), from the episodes the
    learner heard of it; served in the learner's run record, kept in its checkpoint."""

    def __init__(self) -> None:
        self.next: dict[int, int] = {}

    def check(self, er: EpisodeRollout, base: int, sender: int | None) -> int:
        """The worker of episode `er` (its seed minus `base`, the seed worker 0 plays), noted as
        heard; BadMessage for a seed no worker plays, one not the worker `sender`'s (the id in
        the key it came on: a secure run's ACL lets only that worker's certificate put there),
        or an episode at or before one heard from
        that worker already (a worker's episodes come in order on its one link: an earlier one
        is a replay, or a restarted worker's the learner had still queued)."""
        worker = er.seed - base
        if not 0 <= worker <= MAX_WORKER_ID:
            raise BadMessage(f"seed {er.seed} is no rollout worker's of this run")
        if worker != sender:
            raise BadMessage(f"seed {er.seed} is rollout worker {worker}'s, sent on worker "
                             f"{sender}'s key")
        nxt = self.next.get(worker)
        if nxt is not None and er.ep < nxt:
            raise BadMessage(f"episode {er.ep} of rollout worker {worker} heard already (a "
                             f"replay, or a restarted worker's the learner had queued: its "
                             f"next is {nxt})")
        self.heard(worker, er.ep)
        return worker

    def heard(self, worker: int, ep: int) -> None:
        """Worker `worker`'s next episode is past `ep` (kept for at most MAX_WORKERS workers;
        at most BIG, which the run record must hold)."""
        if worker in self.next or len(self.next) < MAX_WORKERS:
            self.next[worker] = max(self.next.get(worker, 0), min(ep + 1, BIG))

    def resume(self, table: Any, where: str) -> None:
        """A checkpoint's table; one out of range is dropped and said, not a refusal."""
        try:
            self.next = check_worker_next(table, "workers") or {}
        except ConfigError as exc:
            log.warning("learner: %s: %s; dropped (restarted workers start from 0)", where, exc)
