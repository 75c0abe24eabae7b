"""`central`: one planner for the whole team with perfect communication (not decentralized).

What it knows. Every robot's trajectory message of every tick so far, whoever could hear it
(the perfect radio: `View.hears` is ignored): the team's belief is the union of all patches seen
(the latest observation of a cell wins, so dynamic blocks show up once seen), the union of the
visited bitmaps and every robot's position. It never reads the world, the episode's future
dynamic-block schedule or a cell nobody has seen; unknown cells are assumed free.

How it plans (heuristic, horizon-limited, re-planned every tick). Prioritized planning: robots
are planned one after another (a rotating order), each by a beam search over its next
`horizon` moves (`beam` states per step) against the paths fixed by the robots planned before
it this tick. A path scores `gamma^t` for each target cell it enters first (not explored by the
team and not claimed by an earlier robot's path), minus `crowd` per step it shares a cell with
an earlier robot's planned position at the same time, plus a terminal estimate
`-lam * (BFS distance on the belief from its end cell to the nearest target nobody claimed)`
(`grid_search.distance_fields`), which is also the beam's ranking heuristic. The cells around an
earlier robot's end cell count as claimed for that distance, so robots spread to different
frontiers beyond the horizon. Only known-free or unknown cells are entered; the first move is
always into a seen cell (vision >= 3), so the team never hits a known block. Everything is
vectorized over the view's groups (episodes): one numpy beam per robot slot for all episodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from policies.base import Policy
from policies.belief import BLOCK, FREE, UNKNOWN
from policies.grid_search import UNREACHED, dilate, distance_fields, pack
from world.config import WorldConfig
from world.core import ACTIONS
from world.decentral import View
from world.noise import hash64, uniform


@dataclass(frozen=True)
class CentralConfig:
    """Search settings of the central planner."""

    horizon: int = 6
    """Moves looked ahead by each robot's beam search."""
    beam: int = 24
    """Beam width (states kept per step and episode)."""
    gamma: float = 0.97
    """Discount of a target cell entered t steps ahead (earlier is better)."""
    lam: float = 0.6
    """Weight of the terminal distance-to-unclaimed-target estimate."""
    crowd: float = 0.5
    """Penalty for sharing a cell with an earlier-planned robot at the same step."""
    spread: int = 2
    """Chebyshev radius around an earlier robot's end cell counted as claimed for the distance."""
    passes: int = 2
    """Rounds of prioritized planning; from the second, a robot re-plans against all others."""


class CentralPolicy(Policy):
    """Centralized prioritized beam planner over the team's pooled belief."""

    name = "central"
    decentralized: ClassVar[bool] = False
    learned: ClassVar[bool] = False

    def __init__(self, cfg: WorldConfig, search: CentralConfig | None = None) -> None:
        super().__init__(cfg)
        self.search = search or CentralConfig()
        h, w = cfg.height, cfg.width
        y, x = np.divmod(np.arange(h * w), w)
        ny, nx = y[:, None] + ACTIONS[None, :, 0], x[:, None] + ACTIONS[None, :, 1]
        self.nbr = np.where((ny >= 0) & (ny < h) & (nx >= 0) & (nx < w), ny * w + nx, -1)
        self.zob = hash64(0x5EED, np.arange(h * w))
        r = cfg.vision // 2
        dy, dx = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij")
        self.win_y, self.win_x = dy.ravel(), dx.ravel()
        self.known = np.zeros((0, h * w), dtype=np.uint8)
        self.explored = np.zeros((0, h * w), dtype=bool)

    def reset(self, groups: int) -> None:
        cells = self.cfg.cells
        self.known = np.zeros((groups, cells), dtype=np.uint8)
        self.explored = np.zeros((groups, cells), dtype=bool)

    def update(self, view: View) -> None:
        """Fold every present message of this tick into the team belief of its group."""
        cfg = self.cfg
        if self.known.shape[0] != view.groups or view.tick == 0:
            self.reset(view.groups)
        m = view.msgs
        g, j = np.nonzero(m.present)
        y = m.pos[g, j, 0, None] + self.win_y
        x = m.pos[g, j, 1, None] + self.win_x
        code = m.patch[g, j].reshape(len(g), -1) & 3
        inside = (y >= 0) & (y < cfg.height) & (x >= 0) & (x < cfg.width)
        gg = np.broadcast_to(g[:, None], y.shape)
        self.known[gg[inside], (y * cfg.width + x)[inside]] = np.where(code == 0, FREE,
                                                                        BLOCK)[inside]
        visited = (m.visited & m.present[:, :, None]).any(1)
        if cfg.explore_mode == "visit":
            self.explored |= visited
        else:
            self.explored |= self.known != UNKNOWN

    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        self.update(view)
        out = np.zeros(view.receivers.shape, dtype=np.int64)
        live = np.flatnonzero(view.msgs.present.any(1))
        if len(live):
            out[live] = self.plan(view, live)
        return np.where(view.receivers, out, 0)

    def plan(self, view: View, groups: np.ndarray) -> np.ndarray:
        """First moves [len(groups), N] of the prioritized beam plans of `groups`."""
        cfg, s = self.cfg, self.search
        h, w, hw, n = cfg.height, cfg.width, cfg.cells, view.n
        gsz = len(groups)
        present = view.msgs.present[groups]
        pos = view.msgs.pos[groups, :, 0] * w + view.msgs.pos[groups, :, 1]  # [G, N]
        passable = self.known[groups] != BLOCK
        passable[np.arange(gsz)[:, None], pos] = True
        targets = ~self.explored[groups] & passable
        pbits = pack(passable.reshape(gsz, h, w))
        out = np.zeros((gsz, n), dtype=np.int64)
        paths = np.full((gsz, n, s.horizon + 1), -1, dtype=np.int64)
        rows = np.arange(gsz)[:, None]
        steps = np.arange(s.horizon + 1)[None]
        shift = view.tick % n  # rotate who plans first, so no robot always yields
        order = np.roll(np.arange(n), -shift)
        for r in np.tile(order, s.passes):
            others = paths[:, np.arange(n) != r]  # [G, N-1, T'] fixed plans (-1: none yet)
            has = others[:, :, 0] >= 0
            claimed = np.zeros((gsz, hw + 1), dtype=bool)
            claimed[rows[:, :, None], np.where(has[..., None], others, hw)] = True
            occ = np.zeros((gsz, s.horizon + 1, hw + 1), dtype=bool)
            occ[rows[:, :, None], steps[:, None], np.where(has[..., None], others, hw)] = True
            end = np.zeros((gsz, hw + 1), dtype=bool)
            end[rows, np.where(has, others[:, :, -1], hw)] = True
            grown = pack(end[:, :hw].reshape(gsz, h, w))
            for _ in range(s.spread):
                grown = dilate(grown)
            free = targets & ~claimed[:, :hw]
            src = pack(free.reshape(gsz, h, w)) & ~grown
            empty = ~src.any(axis=(1, 2))
            src[empty] = pack(free.reshape(gsz, h, w))[empty]
            dist = distance_fields(pbits, src, w).reshape(gsz, hw).astype(np.float32)
            dist[dist == UNREACHED] = 2.0 * (h + w)
            first, path = self._beam(view, groups, int(r), pos[:, r], passable, free,
                                     occ[:, :, :hw], -s.lam * dist)
            ok = present[:, r]
            out[:, r] = np.where(ok, first, 0)
            paths[:, r] = np.where(ok[:, None], path, -1)
        return out

    def _beam(self, view: View, groups: np.ndarray, robot: int, start: np.ndarray,
              passable: np.ndarray, gain: np.ndarray, occ: np.ndarray,
              term: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One robot's beam search in every group: (first action [G], path [G, horizon+1])."""
        s = self.search
        gsz = len(start)
        gi = np.arange(gsz)[:, None]
        pos = start[:, None]  # [G, B]
        hist = start[:, None, None]  # [G, B, t+1]
        score = np.zeros((gsz, 1), dtype=np.float32)
        key = np.zeros((gsz, 1), dtype=np.uint64)
        first = np.zeros((gsz, 1), dtype=np.int64)
        # (drawn once per episode: `team-beam` plans many receivers of one episode alike)
        eps = np.asarray(view.episodes)[groups]
        eps, back = (eps, slice(None)) if gsz == 1 else np.unique(eps, return_inverse=True)
        noise = uniform(view.seed, eps, view.tick, robot, s.horizon * s.beam * 9,
                        stream=7)[back].astype(np.float32) * 1e-3
        for t in range(1, s.horizon + 1):
            b = pos.shape[1]
            q = self.nbr[pos]  # [G, B, 9]
            qc = np.maximum(q, 0)
            valid = (q >= 0) & passable[gi[:, :, None], qc]
            seen = hist[:, :, 0, None] == qc  # (a loop over t: cheaper than a 4-d any)
            for c in range(1, t):
                seen |= hist[:, :, c, None] == qc
            g_new = gain[gi[:, :, None], qc] & ~seen & valid
            sc = (score[:, :, None] + (s.gamma ** t) * g_new
                  - s.crowd * occ[gi[:, :, None], t, qc]).reshape(gsz, -1)
            k = (key[:, :, None] ^ np.where(g_new, self.zob[qc], np.uint64(0))).reshape(gsz, -1)
            qf = qc.reshape(gsz, -1)
            rank = sc + term[gi, qf] + noise[:, (t - 1) * s.beam * 9:][:, :b * 9]
            rank[~valid.reshape(gsz, -1)] = -np.inf
            dk = k ^ (qf.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15))
            rank[duplicates(dk)] = -np.inf
            keep = min(s.beam, rank.shape[1])
            # a stable sort, not argpartition: which of equal ranks it keeps, and in what order
            # (the next step's noise goes by slot), depended on numpy's SIMD kernel, so on the CPU
            sel = np.argsort(-rank, axis=1, kind="stable")[:, :keep]
            alive = np.isfinite(rank[gi, sel])  # (fancy indexing: take_along_axis costs more)
            sel = np.where(alive, sel, rank.argmax(1)[:, None])  # pad dead slots with the best
            par, act = np.divmod(sel, 9)
            pos = qf[gi, sel]
            hist = np.concatenate([hist[gi, par], pos[..., None]], 2)
            score = sc[gi, sel]
            key = k[gi, sel]
            first = act if t == 1 else first[gi, par]
        best = np.argmax(score + term[gi, pos], axis=1)
        rows = np.arange(gsz)
        return first[rows, best], hist[rows, best]


def duplicates(keys: np.ndarray) -> np.ndarray:
    """[G, C] bool: True where a row's key equals one earlier in the row (the first stays).

    The column index replaces the key's low bits, so one value sort (no argsort, no gather)
    orders equal keys by column; keys equal in their other 64 - log2(C) bits count as equal
    (hashes: a false match has odds ~C^2 / 2^57 a row)."""
    c = keys.shape[1]
    bits = np.uint64(max(1, (c - 1).bit_length()))
    low = (np.uint64(1) << bits) - np.uint64(1)
    s = np.sort((keys & ~low) | np.arange(c, dtype=np.uint64), axis=1)
    hi = s >> bits
    dup = np.zeros(keys.shape, dtype=bool)
    dup[np.arange(len(keys))[:, None], (s[:, 1:] & low).astype(np.intp)] = hi[:, 1:] == hi[:, :-1]
    return dup
