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

import numpy as np

from policies.base import Policy
from policies.belief import Belief, Snapshot
from policies.central import CentralPolicy
from policies.horizon_search import belief_episode, fill, improve, zobrist
from policies.oracle import Episode, to_actions
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig
from world.decentral import View

ITERS, BEAM = 12, 48


def plan_paths(cfg: WorldConfig, known: np.ndarray, explored: np.ndarray, cells: np.ndarray,
               t: int, rng: np.random.Generator) -> tuple[Episode, np.ndarray]:
    """A whole-horizon team plan [N, T-t+1] over the belief, and the belief's episode."""
    ep = belief_episode(cfg, known, explored, cells, t)
    zob = zobrist(cfg, rng)
    n = len(cells)
    paths = np.repeat(ep.starts[:, None], cfg.horizon - t + 1, axis=1)
    paths = fill(ep, paths, np.arange(n), BEAM, rng, zob)
    return ep, improve(ep, paths, np.ones(n, dtype=bool), ITERS, BEAM, rng, zob)


def plan_first_moves(cfg: WorldConfig, known: np.ndarray, explored: np.ndarray, cells: np.ndarray,
                     t: int, rng: np.random.Generator) -> np.ndarray:
    """First moves [N] of a whole-horizon team plan over the belief (unknown = free)."""
    ep, paths = plan_paths(cfg, known, explored, cells, t, rng)
    return to_actions(ep.cfg, paths[:, :2])[0]


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
