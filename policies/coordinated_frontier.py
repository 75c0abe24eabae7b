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


CHUNK_FLOATS = 1 << 22
"""Receivers are assigned in chunks of about this many member-cell costs (16 MB of float32):
a batch of 250 episodes of 50 robots on 40 x 40 would otherwise need gigabytes."""


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

    def costs(self, view: View, snap: Snapshot, rows: slice
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For receivers `rows` (the R' of one chunk): the cells some member may take, cols [C]
        (y*W+x ascending); V [R', K, C] float32, member k's path cost to each of them on the
        receiver's belief (inf: unreachable or not a target there); the members [R', K] (ids
        ascending; -1 pads a receiver that heard fewer than K, the most any receiver heard)."""
        r_loc, j = np.nonzero(view.hears[snap.g[rows], snap.i[rows]])  # receiver-major, j up
        n_r = len(snap.g[rows])
        count = np.bincount(r_loc, minlength=n_r)
        k = int(count.max()) if len(j) else 0
        slot = np.arange(len(j)) - np.repeat(np.cumsum(count) - count, count)
        members = np.full((n_r, k), -1, dtype=np.int64)
        members[r_loc, slot] = j
        r = rows.start + r_loc
        h, w = self.cfg.height, self.cfg.width
        src = cell_bits(view.msgs.pos[snap.g[r], j], h, snap.passable_bits.shape[-1])
        dist = distance_fields(snap.passable_bits[r], src, w, targets=snap.targets_bits[r],
                               extra=math.floor(1.0 / self.beta))
        d = dist.reshape(len(j), -1)
        ok = (d != UNREACHED) & snap.targets.reshape(snap.size, -1)[r]
        cols = np.flatnonzero(ok.any(0))
        cost = np.full((n_r, k, len(cols)), np.inf, dtype=np.float32)
        cost[r_loc, slot] = np.where(ok[:, cols], d[:, cols].astype(np.float32), np.inf)
        return cols, cost, members

    def discount(self, cells: np.ndarray) -> np.ndarray:
        """P(d) of every cell for assigned target cells [K] (y*W+x): [K, H*W] float32."""
        y, x = np.divmod(cells, self.cfg.width)
        return np.minimum(self._py[y][:, :, None], self._px[x][:, None, :]).reshape(len(cells), -1)

    def assign(self, view: View, snap: Snapshot) -> np.ndarray:
        """Greedy assignment per receiver; returns its own target cell y*W+x [R] (-1: none).
        Receivers are independent, so they go in chunks that bound the [R', K, cells] arrays."""
        target = np.full(snap.size, -1, dtype=np.int64)
        heard = int(view.hears[snap.g, snap.i].sum(1).max()) if snap.size else 0
        step = max(1, CHUNK_FLOATS // max(1, heard * self.cfg.cells))
        for lo in range(0, snap.size, step):
            target[lo:lo + step] = self._assign(view, snap, slice(lo, min(lo + step, snap.size)))
        return target

    def _assign(self, view: View, snap: Snapshot, rows: slice) -> np.ndarray:
        """`assign` for the receivers `rows`.

        Each greedy round takes, per receiver, the best (member, cell) pair of
        U(t) - beta V_j(t) (+ the tie-breaking noise) over the members not yet assigned, the
        first in (member id, cell) order among equals. Each member row keeps its best cell and
        value; a round only lowers U near the cell it assigns, so only the rows whose best cell
        was lowered are searched again: the same pairs as a full search every round
        (`tests/test_frontier.py` checks it against one), at a fraction of its cost on large
        teams and maps.
        """
        cols, score, members = self.costs(view, snap, rows)
        n_r, k = members.shape
        target = np.full(n_r, -1, dtype=np.int64)
        if not len(cols) or not k:
            return target
        groups, gi = np.unique(snap.g[rows], return_inverse=True)
        noise = uniform(view.seed, view.episodes[groups][:, None], view.tick,
                        np.arange(view.n)[None], self.cfg.cells, stream=3)[..., cols]
        score *= -self.beta  # (in place: the cost array becomes the score, [R', K, C])
        score += 1e-4 * noise.astype(np.float32)[gi[:, None], np.maximum(members, 0)]
        util = snap.targets.reshape(snap.size, -1)[rows][:, cols].astype(np.float32)  # [R', C]
        s = score + util[:, None, :]
        best = s.argmax(2)  # [R', K] each member row's best cell and its value
        value = np.take_along_axis(s, best[..., None], axis=2)[..., 0]
        mine = members == snap.i[rows][:, None]
        taken = np.zeros((n_r, k), dtype=bool)
        todo = np.arange(n_r)
        while len(todo):
            v = np.where(taken[todo], -np.inf, value[todo])
            m = v.argmax(1)
            c = best[todo, m]
            live = np.isfinite(v[np.arange(len(todo)), m])
            own = live & mine[todo, m]
            target[todo[own]] = cols[c[own]]
            taken[todo, m] = True
            hit = self.discount(cols[c])[:, cols] * live[:, None]
            util[todo] = np.maximum(util[todo] - hit, 0.0)
            again = np.take_along_axis(hit > 0, best[todo], axis=1) & ~taken[todo]
            ti, ki = np.nonzero(again)
            if len(ti):
                r = todo[ti]
                row = score[r, ki] + util[r]
                best[r, ki] = row.argmax(1)
                value[r, ki] = row[np.arange(len(r)), best[r, ki]]
            todo = todo[live & ~own]
        return target
