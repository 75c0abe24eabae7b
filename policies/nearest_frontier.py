"""Nearest frontier (Yamauchi 1997): every robot walks a shortest path to its nearest frontier.

Each receiver plans on its own belief (`policies.belief`): a frontier target is a cell the team
has not explored (visit mode: nobody stood on it; sense mode: nobody saw it) and not known to be
a block; unknown cells are assumed passable. One multi-source wavefront from all targets gives
every receiver its distance and *all* first moves that start a shortest path
(`grid_search.steps_toward`).

Ties matter: identical greedy robots that pick the same first move among equals clump and
collide. Among the shortest-path first moves a robot prefers one whose cell holds no robot now
(the robot bit of its own patch), then the one the counter-based noise (stream 1, keyed by the
receiver) ranks highest. A robot with no reachable target stays. This class is also the
skeleton of the other frontier baselines: they override `first_moves`.
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


CW = 1.0
MODE = 'diverge'

class NearestFrontier(Policy):
    name = "nearest-frontier"

    def __init__(self, cfg: WorldConfig) -> None:
        super().__init__(cfg)
        self.belief = Belief(cfg)
        c = cfg.vision // 2
        self._nb_patch = (c + ACTIONS[:, 0]) * cfg.vision + c + ACTIONS[:, 1]  # [9] in a patch
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
        """One of `moves` per receiver: a cell without a robot first, then the noise; else stay."""
        robots = (view.msgs.patch[snap.g, snap.i].reshape(snap.size, -1) & ROBOT_BIT) > 0
        robots[:, self._nb_patch[0]] = False
        occupied = robots[:, self._nb_patch]
        contested = (robots[:, self._around] & self._around_ok).sum(-1)
        u = uniform(view.seed, view.episodes[snap.g], view.tick, snap.i, 9, stream=1)
        pos = view.msgs.pos[snap.g]  # [R, N, 2]
        same = (pos == snap.cells[:, None]).all(-1) & view.hears[snap.g, snap.i]
        same &= np.arange(view.n)[None] < snap.i[:, None]
        stacked = same.any(1)
        if MODE == "stay":
            moves = np.where(stacked[:, None], np.eye(9, dtype=bool)[0], moves)
        elif MODE == "diverge":
            nb = Neighbourhood(snap.cells, self.cfg.height, self.cfg.width)
            pas = nb(snap.passable_bits)
            alt = pas & ~moves
            alt[:, 0] = False
            tg = nb(snap.targets_bits)
            u = u + np.where(stacked[:, None], tg, 0)
            moves = np.where((stacked & alt.any(1))[:, None], alt, moves)
        score = np.where(moves, u - 2 * occupied - CW * contested, -np.inf)
        return np.where(moves.any(1), score.argmax(1), 0)
