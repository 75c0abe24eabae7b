"""Which of a learner's ready episodes make its next batch (`Learner.maybe_update`).

Every tick of a batch must have a decision in some episode of it (the features of a tick where
nobody decided crash): an episode with a tick where every robot was late or down waits for a
batch whose other episodes decided at that tick; it goes stale if none comes in time, and when
four batches' worth wait with no batch to be made of them, the oldest is dropped. With `by_seed` (a
network whose hint features draw tie-break noise from the views' one seed), a batch holds one
seed's episodes, the seed whose oldest episode waits longest: a worker's episodes batched behind
the swarm's were trained on features they were not played with.
"""

from __future__ import annotations

import numpy as np

from swarm.net.learning import EpisodeRollout


def by_seed(policy: object) -> bool:
    """Whether `policy`'s batches must hold one seed (its hint features draw noise from it)."""
    return getattr(getattr(policy, "features", None), "hint", None) is not None


def _covering(decided: list[np.ndarray], size: int) -> list[int] | None:
    """Positions of `size` episodes (of `decided`, each's ticks with a decision, in arrival
    order) that leave no tick undecided, as early as can be: from each start in turn, the
    episodes that decide a tick still undecided, then the oldest others; None if none."""
    for start in range(len(decided) - size + 1):
        chosen, done = [start], decided[start].copy()
        for k in range(start + 1, len(decided)):
            if done.all() or len(chosen) == size:
                break
            if (decided[k] & ~done).any():
                chosen.append(k)
                done |= decided[k]
        if done.all():
            rest = [k for k in range(len(decided)) if k not in chosen][:size - len(chosen)]
            return sorted(chosen + rest)
    return None


def next_batch(ready: list[EpisodeRollout], size: int, by_seed: bool = False
               ) -> list[int] | None:
    """Where in `ready` the next batch of `size` is (`_covering`, one seed's with `by_seed`),
    None until there is one."""
    if len(ready) < size:
        return None
    groups: dict[int, list[int]] = {}
    for k, e in enumerate(ready):
        groups.setdefault(e.seed if by_seed else 0, []).append(k)
    for idx in groups.values():
        if len(idx) >= size and (pos := _covering([ready[k].receivers.any(1) for k in idx],
                                                  size)) is not None:
            return [idx[p] for p in pos]
    return None


def fresh(ready: list[EpisodeRollout], version: int, max_staleness: int
          ) -> list[EpisodeRollout]:
    """The waiting episodes at most `max_staleness` versions behind `version`."""
    return [e for e in ready if version - e.version <= max_staleness]


def take_batch(ready: list[EpisodeRollout], size: int, by_seed: bool, version: int,
               max_staleness: int) -> tuple[list[EpisodeRollout] | None, list[EpisodeRollout],
                                            int, int]:
    """(the next batch or None, the episodes left waiting, how many went stale while they
    waited, how many of the oldest were dropped because 4 batches' worth waited and no batch
    could be made of them)."""
    waiting = fresh(ready, version, max_staleness)
    stale, blocked = len(ready) - len(waiting), 0
    while (where := next_batch(waiting, size, by_seed)) is None and len(waiting) >= 4 * size:
        waiting, blocked = waiting[1:], blocked + 1
    if where is None:
        return None, waiting, stale, blocked
    taken = set(where)
    return ([waiting[k] for k in where], [e for k, e in enumerate(waiting) if k not in taken],
            stale, blocked)
