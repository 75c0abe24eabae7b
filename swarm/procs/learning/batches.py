"""Which of a learner's ready episodes make its next batch (`Learner.maybe_update`).

A batch's views share one seed, which hint features draw their tie-break noise from: a batch
is the first `size` episodes of one seed, the seed whose oldest episode waits longest (a
worker's episodes batched behind the swarm's were trained on features they were not played
with). And every tick of a batch must have a decision in some episode of it (the features of
a tick where nobody decided crash): an episode with a tick where every robot was late or down
goes only into a batch whose others cover that tick.
"""

from __future__ import annotations

import numpy as np

from swarm.net.learning import EpisodeRollout


def next_batch(ready: list[EpisodeRollout], size: int) -> list[int] | None:
    """Where in `ready` the next batch of `size` is (one seed's first episodes), None until
    one seed has that many."""
    if len(ready) < size:
        return None
    by_seed: dict[int, list[int]] = {}
    for k, e in enumerate(ready):
        by_seed.setdefault(e.seed, []).append(k)
    return next((idx[:size] for idx in by_seed.values() if len(idx) >= size), None)


def take_batch(ready: list[EpisodeRollout], size: int
               ) -> tuple[list[EpisodeRollout] | None, list[EpisodeRollout], list[int]]:
    """(the next batch or None, the episodes left ready, the ticks of the episodes dropped):
    the episodes that leave a tick of their batch with no decision are dropped (the caller
    counts them rejected, one tick each named), and the batch is looked for again."""
    dropped: list[int] = []
    while (where := next_batch(ready, size)) is not None:
        batch = [ready[k] for k in where]
        quiet = ~np.stack([e.receivers.any(1) for e in batch])  # [B, T]
        uncovered = quiet.all(0)
        if not uncovered.any():
            return batch, [e for k, e in enumerate(ready) if k not in set(where)], dropped
        drop = {where[b] for b in np.flatnonzero(quiet[:, uncovered].any(1))}
        dropped += [int(np.argmax(uncovered))] * len(drop)
        ready = [e for k, e in enumerate(ready) if k not in drop]
    return None, ready, dropped
