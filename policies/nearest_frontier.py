"""Nearest frontier (Yamauchi 1997): every robot walks a shortest path to its nearest frontier.

Each receiver plans on its own belief (`policies.belief`): a frontier target is a cell the team
has not explored (visit mode: nobody stood on it; sense mode: nobody saw it) and not known to be
a block; unknown cells are assumed passable. One multi-source wavefront from all targets gives
every receiver its distance and *all* first moves that start a shortest path
(`grid_search.steps_toward`).

Ties matter: identical greedy robots that pick the same first move among equals clump and
collide. So, among the shortest-path first moves, a robot prefers a cell that holds no robot
now, then one with the fewest robots next to it (robot bits of its own patch), then the
counter-based noise (stream 1, keyed by the receiver); and a robot sharing its cell with a
lower-id robot it heard steps off the path for one tick so the pair splits (see `pick`). On the
default dynamic world that takes robot collisions per episode from 50 (noise-only ties) to 25
(robot preferences) to 7 (split). These are local tie-break rules, not coordination: no robot
plans for another. A robot with no reachable
target stays. This class is also the skeleton of the other frontier baselines: they override
`first_moves`.
"""

from __future__ import annotations

import numpy as np

from policies.base import Policy
from policies.belief import Belief, Snapshot
from policies.grid_search import Neighbourhood, steps_toward
from world.config import WorldConfig
from world.core import ACTIONS, ROBOT_BIT
from world.decentral import View
from world.noise import uniform


class NearestFrontier(Policy):
    name = "nearest-frontier"

    def __init__(self, cfg: WorldConfig) -> None:
        super().__init__(cfg)
        self.belief = Belief(cfg)
        c = cfg.vision // 2
        self._nb_patch = (c + ACTIONS[:, 0]) * cfg.vision + c + ACTIONS[:, 1]  # [9] in a patch
        # [9 moves, 9 cells around the move's cell] in the patch, for counting nearby robots
        ny = c + ACTIONS[:, 0, None] + ACTIONS[None, :, 0]
        nx = c + ACTIONS[:, 1, None] + ACTIONS[None, :, 1]
        self._around = np.clip(ny, 0, cfg.vision - 1) * cfg.vision + np.clip(nx, 0, cfg.vision - 1)
        self._around_ok = (ny >= 0) & (ny < cfg.vision) & (nx >= 0) & (nx < cfg.vision)

    def reset(self, groups: int) -> None:
        self.belief.reset(groups)

    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        snap = self.belief.snapshot(view)
        out = np.zeros(view.receivers.shape, dtype=np.int64)
        if snap.size:
            out[snap.g, snap.i] = self.pick(view, snap, self.first_moves(view, snap))
        return out

    def first_moves(self, view: View, snap: Snapshot) -> np.ndarray:
        """[R, 9] bool: the moves that start a shortest path to the receiver's target."""
        return steps_toward(snap.passable_bits, snap.targets_bits, snap.cells)[1]

    def pick(self, view: View, snap: Snapshot, moves: np.ndarray) -> np.ndarray:
        """One of `moves` [R, 9] per receiver (stay when there is none), actions [R].

        Ranked by: no robot on the cell now, fewest robots next to it (they may move there),
        then the noise. A receiver sharing its cell with a lower-id robot it heard steps off
        the shortest path instead (onto an unexplored cell where it can), so robots that landed
        on one cell split up rather than march on together.
        """
        nb = Neighbourhood(snap.cells, self.cfg.height, self.cfg.width)
        pos = view.msgs.pos[snap.g]  # [R, N, 2]
        below = (pos == snap.cells[:, None]).all(-1) & view.hears[snap.g, snap.i]
        stacked = (below & (np.arange(view.n)[None] < snap.i[:, None])).any(1)
        off_path = nb(snap.passable_bits) & ~moves
        off_path[:, 0] = False
        split = stacked & off_path.any(1)
        moves = np.where(split[:, None], off_path, moves)
        robots = (view.msgs.patch[snap.g, snap.i].reshape(snap.size, -1) & ROBOT_BIT) > 0
        robots[:, self._nb_patch[0]] = False  # the receiver itself
        occupied = robots[:, self._nb_patch]
        around = (robots[:, self._around] & self._around_ok).sum(-1)
        u = uniform(view.seed, view.episodes[snap.g], view.tick, snap.i, 9, stream=1)
        fresh = split[:, None] & nb(snap.targets_bits)
        score = np.where(moves, 16.0 * fresh - 8.0 * occupied - around + u, -np.inf)
        return np.where(moves.any(1), score.argmax(1), 0)
