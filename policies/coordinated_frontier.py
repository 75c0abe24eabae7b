"""Coordinated frontier exploration (Burgard et al. 2005), run by every receiver on its own.

Receiver i takes the robots it heard this tick (itself included) and, on ITS OWN belief,
computes each member's path cost V_j(t) to every frontier cell t (one bit-parallel wavefront
per member, `grid_search.distance_fields`). Every target starts with utility U(t) = 1. Greedy
rounds then pick the (member, target) pair with the highest U(t) - beta * V_j(t), assign it,
and discount the utility of the cells near t by the probability P(d) that they are covered
by the robot going to t, P(d) = max(0, 1 - d / (reach + 1)) for Chebyshev distance d (the
paper's visibility-based discount; `reach` is the vision radius). U never drops below 0.
Rounds stop as soon as receiver i itself has a target; it walks the first step of a shortest
path to it, tie-broken like nearest frontier.

Since a target more than 1 / beta steps further than a member's nearest one can never win, each
wavefront stops that many layers after touching its first target. Deviation from the paper: the
assignment noise that breaks exact ties is keyed by (seed, episode, tick, member, cell), not by
the receiver, so two receivers with the same belief agree on the whole assignment.
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


def _profile(n: int, reach: int) -> np.ndarray:
    """max(0, 1 - |a - b| / (reach + 1)) for a, b in 0..n-1: [n, n] float32."""
    d = np.abs(np.arange(n)[:, None] - np.arange(n)[None])
    return np.clip(1.0 - d / (reach + 1), 0.0, None).astype(np.float32)


class CoordinatedFrontier(NearestFrontier):
    name = "coordinated-frontier"

    def __init__(self, cfg: WorldConfig, beta: float = 0.25, reach: int | None = None) -> None:
        super().__init__(cfg)
        self.beta = beta
        """Weight of the path cost against the (0..1) utility."""
        self.reach = cfg.vision // 2 if reach is None else reach
        """Chebyshev radius over which an assigned target discounts its neighbours."""
        # P(d) of a Chebyshev distance is the min of the per-axis profiles, [H, H] and [W, W]
        self._py = _profile(cfg.height, self.reach)
        self._px = _profile(cfg.width, self.reach)

    def first_moves(self, view: View, snap: Snapshot) -> np.ndarray:
        target = self.assign(view, snap)
        h, w = self.cfg.height, self.cfg.width
        ok = target >= 0
        moves = np.zeros((snap.size, 9), dtype=bool)
        if ok.any():
            cells = np.stack(np.divmod(target[ok], w), axis=-1)
            tbits = cell_bits(cells, h, snap.passable_bits.shape[-1])
            moves[ok] = steps_toward(snap.passable_bits[ok], tbits, snap.cells[ok])[1]
        return moves

    def costs(self, view: View, snap: Snapshot) -> np.ndarray:
        """V [R, N, H*W] float32: member j's path cost to each target on receiver r's belief."""
        r_idx, j_idx = np.nonzero(view.hears[snap.g, snap.i])
        h, w = self.cfg.height, self.cfg.width
        src = cell_bits(view.msgs.pos[snap.g[r_idx], j_idx], h, snap.passable_bits.shape[-1])
        dist = distance_fields(snap.passable_bits[r_idx], src, w, targets=snap.targets_bits[r_idx],
                               extra=math.floor(1.0 / self.beta))
        cost = np.full((snap.size, view.n, h * w), np.inf, dtype=np.float32)
        d = dist.reshape(len(r_idx), -1)
        ok = (d != UNREACHED) & snap.targets.reshape(snap.size, -1)[r_idx]
        cost[r_idx, j_idx] = np.where(ok, d.astype(np.float32), np.inf)
        return cost

    def discount(self, cells: np.ndarray) -> np.ndarray:
        """P(d) of every cell for assigned target cells [K] (y*W+x): [K, H*W] float32."""
        y, x = np.divmod(cells, self.cfg.width)
        return np.minimum(self._py[y][:, :, None], self._px[x][:, None, :]).reshape(len(cells), -1)

    def assign(self, view: View, snap: Snapshot) -> np.ndarray:
        """Greedy assignment per receiver; returns its own target cell y*W+x [R] (-1: none)."""
        cost = self.costs(view, snap)
        cols = np.flatnonzero(np.isfinite(cost).any(axis=(0, 1)))  # cells some member may take
        groups, gi = np.unique(snap.g, return_inverse=True)
        noise = uniform(view.seed, view.episodes[groups][:, None], view.tick,
                        np.arange(view.n)[None], self.cfg.cells, stream=3)[..., cols]
        score = -self.beta * cost[..., cols] + 1e-4 * noise.astype(np.float32)[gi]  # [R, N, C]
        util = snap.targets.reshape(snap.size, -1)[:, cols].astype(np.float32)  # [R, C]
        taken = np.zeros((snap.size, view.n), dtype=bool)
        target = np.full(snap.size, -1, dtype=np.int64)
        todo = np.arange(snap.size)
        while len(todo) and len(cols):
            s = score[todo] + util[todo, None, :]
            s[taken[todo]] = -np.inf
            best = s.reshape(len(todo), -1).argmax(1)
            j, c = np.divmod(best, len(cols))
            live = np.isfinite(s.reshape(len(todo), -1)[np.arange(len(todo)), best])
            own = live & (j == snap.i[todo])
            target[todo[own]] = cols[c[own]]
            taken[todo, j] = True
            hit = self.discount(cols[c])[:, cols] * live[:, None]
            util[todo] = np.maximum(util[todo] - hit, 0.0)
            todo = todo[live & ~own]
        return target
