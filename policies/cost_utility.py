"""Cost-utility frontier selection (Gonzalez-Banos & Latombe 2002; Stachniss 2006): gain vs cost.

Each receiver scores every frontier cell t of its own belief by its information gain minus
lambda times its path cost, gain(t) - lambda * V(t), and walks the first step of a shortest
path to the best one. The gain is the number of cells inside the v x v vision window around t
that the team has not explored and does not know to be blocks (2D cumulative sums over the
belief); the cost is the robot's wavefront distance (`grid_search.distance_fields`). Robots
do not coordinate beyond sharing the belief; exact ties go to the counter-based noise keyed by
the receiver (stream 4), and the first step is tie-broken as in nearest frontier.

A target more than max_gain / lambda steps further than the nearest frontier can never win, so
each wavefront stops that many layers after touching its first target.
"""

from __future__ import annotations

import math

import numpy as np

from policies.belief import Snapshot
from policies.grid_search import UNREACHED, cell_bits, distance_fields, steps_toward
from policies.nearest_frontier import NearestFrontier
from world.config import WorldConfig
from world.decentral import View
from world.noise import uniform


def window_sums(mask: np.ndarray, radius: int) -> np.ndarray:
    """Count of set cells within Chebyshev `radius` of every cell: [R, H, W] -> [R, H, W] int."""
    r, h, w = mask.shape
    c = np.zeros((r, h + 1, w + 1), dtype=np.int32)
    np.cumsum(np.cumsum(mask, axis=1, dtype=np.int32), axis=2, out=c[:, 1:, 1:])
    y0 = np.clip(np.arange(h) - radius, 0, h)
    y1 = np.clip(np.arange(h) + radius + 1, 0, h)
    x0 = np.clip(np.arange(w) - radius, 0, w)
    x1 = np.clip(np.arange(w) + radius + 1, 0, w)
    return (c[:, y1][:, :, x1] - c[:, y0][:, :, x1] - c[:, y1][:, :, x0] + c[:, y0][:, :, x0])


class CostUtility(NearestFrontier):
    name = "cost-utility"

    def __init__(self, cfg: WorldConfig, lam: float | None = None,
                 radius: int | None = None) -> None:
        super().__init__(cfg)
        self.lam = float(cfg.vision) if lam is None else lam
        """Gain (cells) per step of path cost; default v, the most one step of sensing reveals."""
        self.radius = cfg.vision // 2 if radius is None else radius
        """Half side of the window whose unexplored cells count as a target's gain."""

    def first_moves(self, view: View, snap: Snapshot) -> np.ndarray:
        h, w = self.cfg.height, self.cfg.width
        gain = window_sums(snap.targets, self.radius)
        max_gain = (2 * self.radius + 1) ** 2
        src = cell_bits(snap.cells, h, snap.passable_bits.shape[-1])
        dist = distance_fields(snap.passable_bits, src, w, targets=snap.targets_bits,
                               extra=math.ceil(max_gain / self.lam))
        ok = snap.targets & (dist != UNREACHED)
        u = uniform(view.seed, view.episodes[snap.g], view.tick, snap.i, h * w, stream=4)
        utility = gain - self.lam * dist.astype(np.float32) + 1e-3 * u.reshape(-1, h, w)
        utility = np.where(ok, utility, -np.inf).reshape(snap.size, -1)
        best = utility.argmax(1)
        has = ok.reshape(snap.size, -1).any(1)
        moves = np.zeros((snap.size, 9), dtype=bool)
        if has.any():
            cells = np.stack(np.divmod(best[has], w), axis=-1)
            tbits = cell_bits(cells, h, snap.passable_bits.shape[-1])
            moves[has] = steps_toward(snap.passable_bits[has], tbits, snap.cells[has])[1]
        return moves
