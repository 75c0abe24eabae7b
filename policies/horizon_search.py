"""Whole-horizon team search over one robot's belief: the oracle's per-robot beam (`_beam`) and
team local search, on the steps left of an episode as a belief knows it (known blocks block,
unknown cells are free and score, no dynamic block is foreseen).

Used by `chain-plan` (policies/chain_plan.py) and the re-planners of results/planners/.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from policies.belief import BLOCK
from policies.oracle import Episode, _beam, _cover, _pick_team
from world import core
from world.config import WorldConfig

GROUPS, BOOSTS = (2, 2, 3), (1, 1, 3)  # local search: robots re-planned per round, missing boost


def belief_episode(cfg: WorldConfig, known: np.ndarray, explored: np.ndarray, cells: np.ndarray,
                   t: int) -> Episode:
    """The steps left after tick `t` in the planner's terms: `known` [HW] (policies.belief codes),
    `explored` [HW] bool, the team's cells [N] (flat y*W+x)."""
    left = cfg.horizon - t
    ecfg = SimpleNamespace(horizon=left, width=cfg.width, cells=cfg.cells)  # the steps left
    block = known == BLOCK
    block[cells] = False  # where a robot stands is free
    due = np.where(block, -1, left + 1).astype(np.int64)
    h, w = cfg.height, cfg.width
    y, x = np.divmod(np.arange(h * w), w)
    ny, nx = y[:, None] + core.ACTIONS[None, :, 0], x[:, None] + core.ACTIONS[None, :, 1]
    ok = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
    nbr = np.where(ok, ny * w + nx, -1)
    nbr[ok] = np.where(due[nbr[ok]] < 0, -1, nbr[ok])
    value = ~explored & ~block
    value[cells] = False
    return Episode(ecfg, cells.astype(np.int64), nbr, due, value, 0)  # type: ignore[arg-type]


def zobrist(cfg: WorldConfig, rng: np.random.Generator) -> np.ndarray:
    """The beam's per-cell hash keys."""
    return rng.integers(0, np.iinfo(np.int64).max, cfg.height * cfg.width,
                        dtype=np.int64).astype(np.uint64)


def fill(ep: Episode, paths: np.ndarray, todo: list[int] | np.ndarray, beam: int,
         rng: np.random.Generator, zob: np.ndarray) -> np.ndarray:
    """Plan the robots `todo` (row indices of `paths` [N, T+1], in order) one at a time, each
    around every other path."""
    cov = _cover(ep, paths)
    for r in todo:
        others = cov[np.arange(len(paths)) != r].any(0)
        paths[r] = _beam(ep, int(ep.starts[r]), ep.value & ~others, beam, rng, zob)
        cov[r] = _cover(ep, paths[r:r + 1])[0]
    return paths


def improve(ep: Episode, paths: np.ndarray, movable: np.ndarray, iters: int, beam: int,
            rng: np.random.Generator, zob: np.ndarray) -> np.ndarray:
    """Team local search over `paths` [N, T+1]: `iters` rounds, each re-planning a few of the
    robots `movable` [N] bool around the rest, kept if the team covers no fewer cells."""
    n = len(paths)
    cov = _cover(ep, paths)
    covered = int(cov.any(0).sum())
    mov = np.flatnonzero(movable)
    if len(mov) == 0:
        return paths
    yx = np.stack(np.divmod(np.arange(len(ep.due)), ep.cfg.width), axis=-1)
    for _ in range(iters):
        team = mov[_pick_team(yx, paths[mov], ep.value & ~cov.any(0), int(rng.choice(GROUPS)),
                              rng)]
        new_paths, new_cov = paths.copy(), cov.copy()
        new_cov[team] = False
        missing = ep.value & ~cov.any(0)
        boost = int(rng.choice(BOOSTS))
        for k, r in enumerate(team):
            others = new_cov[np.arange(n) != r].any(0)
            weight = (ep.value & ~others).astype(np.int64)
            if k == 0:
                weight[missing & ~others] = boost
            new_paths[r] = _beam(ep, int(ep.starts[r]), weight, beam, rng, zob)
            new_cov[r] = _cover(ep, new_paths[r:r + 1])[0]
        if int(new_cov.any(0).sum()) >= covered:
            paths, cov, covered = new_paths, new_cov, int(new_cov.any(0).sum())
    return paths
