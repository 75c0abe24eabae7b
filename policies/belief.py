"""Each receiver's belief map, built only from the trajectory messages it heard (SPEC section 3).

The frontier baselines keep one belief per (group, robot) slot, [G, N, ...]. At every tick a
receiver i folds in the messages it heard (its own included): the v x v patches of the heard
robots set cells known free or known block (the latest observation wins, so a dynamic block
overwrites an older "free"), and their visited bitmaps are ORed into the team-visited map. Rows
of robots that are not receivers this tick are never touched, so a robot process that holds
only its own row computes exactly what the batched evaluator computes for that row. A receiver's
row is cleared at tick 0 (a new episode) even if nobody called `reset`.

`explored` is what the team has covered: visited cells in `visit` mode, seen cells in `sense`
mode. Frontier targets are the cells not explored and not known to be blocks (unknown cells
included: the planner is optimistic about what it has not seen).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from policies.base import receiver_index
from policies.grid_search import pack
from world.config import WorldConfig
from world.decentral import TeamMemory, View

UNKNOWN, FREE, BLOCK = 0, 1, 2  # codes of `Belief.known`


@dataclass
class Snapshot:
    """The beliefs of this tick's R receivers, ready for the searches."""

    g: np.ndarray  # [R] group of each receiver
    i: np.ndarray  # [R] robot id of each receiver
    cells: np.ndarray  # [R, 2] (y, x) own position
    known: np.ndarray  # [R, H, W] uint8 UNKNOWN / FREE / BLOCK
    explored: np.ndarray  # [R, H, W] bool covered by the team as far as the receiver knows
    targets: np.ndarray  # [R, H, W] bool frontier cells: not explored, not known block
    passable: np.ndarray  # [R, H, W] bool: not known block
    passable_bits: np.ndarray  # [R, H, Wd] uint64 (grid_search.pack)
    targets_bits: np.ndarray  # [R, H, Wd] uint64

    @property
    def size(self) -> int:
        return len(self.g)


class Belief:
    """Per-receiver known-cell and team-visited maps, [G, N, ...], updated from heard messages."""

    def __init__(self, cfg: WorldConfig) -> None:
        self.cfg = cfg
        self.pad = cfg.vision // 2
        self.hp, self.wp = cfg.height + 2 * self.pad, cfg.width + 2 * self.pad
        r = self.pad
        dy, dx = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij")
        self.window = (dy * self.wp + dx).ravel()  # flat offsets of a patch, row-major
        self.known = np.zeros((0, cfg.n_robots, self.hp, self.wp), dtype=np.uint8)
        self.team = TeamMemory(cfg)

    @property
    def visited(self) -> np.ndarray:
        """[G, N, H*W] the team-visited map of each slot (world.decentral.TeamMemory)."""
        return self.team.visited

    def reset(self, groups: int) -> None:
        n = self.cfg.n_robots
        self.known = np.zeros((groups, n, self.hp, self.wp), dtype=np.uint8)  # padded grid
        self.team.reset(groups)

    def update(self, view: View) -> None:
        """Fold the messages each receiver heard this tick into its own row (tick 0 clears it)."""
        if self.known.shape[0] != view.groups:
            self.reset(view.groups)
        if view.tick == 0:  # a new episode, even if nobody called reset
            self.known[view.receivers] = UNKNOWN
        n = self.cfg.n_robots
        g, i = np.nonzero(view.receivers)  # the receivers' rows only, in (g, i, j) order
        r, j = np.nonzero(view.hears[g, i])
        g, i = g[r], i[r]
        pos = view.msgs.pos[g, j]
        centre = ((g * n + i) * self.hp + pos[:, 0] + self.pad) * self.wp + pos[:, 1] + self.pad
        code = view.msgs.patch[g, j].reshape(len(g), -1) & 3
        # Off-grid cells (code 2) land in the padding, which no search reads.
        self.known.reshape(-1)[centre[:, None] + self.window] = np.where(code == 0, FREE, BLOCK)
        self.team.update(view)

    def snapshot(self, view: View) -> Snapshot:
        """Update with `view`, then the receivers' beliefs in receiver order (group-major)."""
        self.update(view)
        g, i = receiver_index(view)
        cfg = self.cfg
        p = self.pad
        known = self.known[g, i, p:p + cfg.height, p:p + cfg.width]
        block = known == BLOCK
        if cfg.explore_mode == "visit":
            explored = self.visited[g, i].reshape(-1, cfg.height, cfg.width)
        else:
            explored = known != UNKNOWN
        targets = ~explored & ~block
        passable = ~block
        cells = view.msgs.pos[g, i]
        passable[np.arange(len(g)), cells[:, 0], cells[:, 1]] = True  # where the robot stands
        return Snapshot(g=g, i=i, cells=cells, known=known, explored=explored, targets=targets,
                        passable=passable, passable_bits=pack(passable),
                        targets_bits=pack(targets))
