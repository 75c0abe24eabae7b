"""Which of a learner's ready episodes make its next batch (`Learner.maybe_update`).

Every tick of a batch must have a decision in some episode of it (the features of a tick where
nobody decided crash): an episode with a tick where every robot was late or down waits for a
batch whose other episodes decided at that tick (its staleness bound drops it if none comes).
With `by_seed` (a network whose hint features draw tie-break noise from the views' one seed),
a batch holds one seed's episodes, the seed whose oldest episode waits longest: a worker's
episodes batched behind the swarm's were trained on features they were not played with.
"""

from __future__ import annotations

import numpy as np

from swarm.net.learning import EpisodeRollout


def by_seed(policy: object) -> bool:
    """Whether `policy`'s batches must hold one seed (its hint features draw noise from it)."""
    return getattr(getattr(policy, "features", None), "hint", None) is not None


def next_batch(ready: list[EpisodeRollout], size: int, by_seed: bool = False
               ) -> list[int] | None:
    """Where in `ready` the next batch of `size` is, None until there is one: the first
    `size - 1` episodes (of one seed with `by_seed`), then the first after them that leaves no
    tick of the batch undecided."""
    if len(ready) < size:
        return None
    groups: dict[int, list[int]] = {}
    for k, e in enumerate(ready):
        groups.setdefault(e.seed if by_seed else 0, []).append(k)
    for idx in groups.values():
        if len(idx) < size:
            continue
        head = idx[:size - 1]
        decided = np.zeros(ready[idx[0]].receivers.shape[0], bool)
        for k in head:
            decided |= ready[k].receivers.any(1)
        last = next((k for k in idx[size - 1:] if (decided | ready[k].receivers.any(1)).all()),
                    None)
        if last is not None:
            return [*head, last]
    return None


def take_batch(ready: list[EpisodeRollout], size: int, by_seed: bool = False
               ) -> tuple[list[EpisodeRollout] | None, list[EpisodeRollout]]:
    """(the next batch or None, the episodes left waiting)."""
    where = next_batch(ready, size, by_seed)
    if where is None:
        return None, ready
    taken = set(where)
    return [ready[k] for k in where], [e for k, e in enumerate(ready) if k not in taken]
