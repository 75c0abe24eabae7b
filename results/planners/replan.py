"""How far perfect communication and a strong planner get without foresight (issue 17's question:
is 0.95 reachable at all by a team that cannot see the future?).

`replan`: the team's pooled belief of `central` (every message of every robot, no range), and
each tick the oracle's whole-horizon planner (beam search per robot + team local search,
policies/oracle.py) over the steps left, on that belief: known blocks block, unknown cells are
free, no dynamic block is foreseen; the team takes the plan's first moves and re-plans next tick.
Not decentralized, not a shipped policy: a reference point between `central` (a 6-step beam)
and `oracle` (knows the future).

    .venv/bin/python results/planners/replan.py FIRST COUNT OUT.json   # episodes of seed 0
    .venv/bin/python results/planners/replan.py FIRST COUNT OUT.json --decentralized

`--decentralized`: every robot plans alone from what it heard (range 10, its own memory), the
question being whether decentralized planning alone can reach 0.95.
"""
import json
import sys
import time
from types import SimpleNamespace

import numpy as np

from policies.base import Policy
from policies.belief import BLOCK, Belief, Snapshot
from policies.central import CentralPolicy
from policies.oracle import Episode, _beam, _cover, _pick_team, to_actions
from swarm.learn.evaluate import evaluate
from world import core
from world.config import WorldConfig
from world.decentral import View

ITERS, BEAM, GROUPS, BOOSTS = 12, 48, (2, 2, 3), (1, 1, 3)


def plan_first_moves(cfg: WorldConfig, known: np.ndarray, explored: np.ndarray, cells: np.ndarray,
                     t: int, rng: np.random.Generator) -> np.ndarray:
    """First moves [N] of a whole-horizon team plan over the belief (unknown = free)."""
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
    ep = Episode(ecfg, cells.astype(np.int64), nbr, due, value, 0)
    zob = rng.integers(0, np.iinfo(np.int64).max, h * w, dtype=np.int64).astype(np.uint64)
    n = len(cells)
    paths = np.repeat(ep.starts[:, None], left + 1, axis=1)
    cov = _cover(ep, paths)
    for r in range(n):
        others = cov[np.arange(n) != r].any(0)
        paths[r] = _beam(ep, int(ep.starts[r]), ep.value & ~others, BEAM, rng, zob)
        cov[r] = _cover(ep, paths[r:r + 1])[0]
    covered = int(cov.any(0).sum())
    yx = np.stack(np.divmod(np.arange(h * w), w), axis=-1)
    for _ in range(ITERS):
        team = _pick_team(yx, paths, value & ~cov.any(0), int(rng.choice(GROUPS)), rng)
        new_paths, new_cov = paths.copy(), cov.copy()
        new_cov[team] = False
        missing = value & ~cov.any(0)
        boost = int(rng.choice(BOOSTS))
        for k, r in enumerate(team):
            others = new_cov[np.arange(n) != r].any(0)
            weight = (ep.value & ~others).astype(np.int64)
            if k == 0:
                weight[missing & ~others] = boost
            new_paths[r] = _beam(ep, int(ep.starts[r]), weight, BEAM, rng, zob)
            new_cov[r] = _cover(ep, new_paths[r:r + 1])[0]
        if int(new_cov.any(0).sum()) >= covered:
            paths, cov, covered = new_paths, new_cov, int(new_cov.any(0).sum())
    return to_actions(ecfg, paths[:, :2])[0]


class Replan(CentralPolicy):
    name = "replan"

    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        self.update(view)
        cfg = self.cfg
        out = np.zeros(view.receivers.shape, dtype=np.int64)
        for g in range(view.groups):
            cells = view.msgs.pos[g, :, 0] * cfg.width + view.msgs.pos[g, :, 1]
            rng = np.random.default_rng([int(view.seed), int(view.episodes[g]), view.tick, 23])
            out[g] = plan_first_moves(cfg, self.known[g].copy(), self.explored[g], cells,
                                      view.tick, rng)
        return np.where(view.receivers, out, 0)


class DecentralizedReplan(Policy):
    """`replan` by every robot alone: its own belief (the blocks it saw or heard of, its team
    memory of visited cells, as nearest frontier keeps them), the robots it hears this tick as
    the team; it plans all of them and takes its own first move."""

    name = "replan-decentralized"

    def __init__(self, cfg: WorldConfig) -> None:
        super().__init__(cfg)
        self.belief = Belief(cfg)

    def reset(self, groups: int) -> None:
        self.belief.reset(groups)

    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        snap = self.belief.snapshot(view)
        out = np.zeros(view.receivers.shape, dtype=np.int64)
        out[snap.g, snap.i] = own_moves(self.cfg, view, snap)
        return out


def own_moves(cfg: WorldConfig, view: View, snap: Snapshot) -> np.ndarray:
    """Each receiver's first move [R] in the whole-horizon plan of its heard team, planned on
    its own belief (`DecentralizedReplan`'s decision; a hint in results/hint_tb/replan_hint.py)."""
    out = np.zeros(snap.size, dtype=np.int64)
    for k in range(snap.size):
        g, i = int(snap.g[k]), int(snap.i[k])
        team = np.flatnonzero(view.hears[g, i])
        cells = view.msgs.pos[g, team, 0] * cfg.width + view.msgs.pos[g, team, 1]
        rng = np.random.default_rng([int(view.seed), int(view.episodes[g]), view.tick, i, 29])
        moves = plan_first_moves(cfg, snap.known[k].ravel().copy(), snap.explored[k].ravel(),
                                 cells, view.tick, rng)
        out[k] = moves[int(np.flatnonzero(team == i)[0])]
    return out


if __name__ == "__main__":
    first, count, path = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    cfg = WorldConfig()
    t0 = time.time()
    runs = {"replan": Replan(cfg), "central": CentralPolicy(cfg)}
    if len(sys.argv) > 4 and sys.argv[4] == "--decentralized":
        runs = {"replan-decentralized": DecentralizedReplan(cfg)}
    res = {k: evaluate(cfg, p, 0, count, first_episode=first, batch=count)
           for k, p in runs.items()}
    out = {k: {"elratio": r.elratio.tolist(), "summary": r.summary(cfg)} for k, r in res.items()}
    out["command"] = "results/planners/replan.py " + " ".join(sys.argv[1:])
    out["seconds"] = time.time() - t0
    with open(path, "w") as fh:
        json.dump(out, fh)
    for k, r in res.items():
        print(k, round(float(r.elratio.mean()), 4))
