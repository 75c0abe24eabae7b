"""What knowing the static map is worth to `chain-plan`: the same planner whose belief holds
every static block from the start (not the dynamic blocks, not their schedule), paired with the
planner as shipped on the same held-out episodes. An upper bound for a learned map prior.

    .venv/bin/python results/planners/static_bound.py FIRST LAST base|cheat > OUT.json

prints one JSON line: per-episode elratio (seed 0, episodes FIRST..LAST-1) and the mean
(`results/planners/static_bound_200.json` pairs the two over episodes 0-199).
"""

import json
import sys
import time

import numpy as np
import torch

from policies import belief as B
from policies import make_policy
from swarm.learn.evaluate import evaluate
from world import core
from world.config import WorldConfig

torch.set_num_threads(1)
CFG = WorldConfig()
MAPS: dict[int, np.ndarray] = {}
SNAPSHOT = B.Belief.snapshot


def static_of(ep: int) -> np.ndarray:
    """The static blocks of held-out episode `ep` of seed 0, [H, W] bool."""
    if ep not in MAPS:
        MAPS[ep] = np.asarray(core.generate_episode(CFG, 0, int(ep))[0], bool)
    return MAPS[ep]


def knowing_the_map(self: B.Belief, view: object) -> B.Snapshot:
    """`Belief.snapshot`, with every unknown static block known as a block."""
    s = SNAPSHOT(self, view)
    for k in range(s.size):
        blk = (s.known[k] == B.UNKNOWN) & static_of(int(view.episodes[s.g[k]]))
        s.known[k][blk] = B.BLOCK
        s.targets[k] &= ~blk
        s.passable[k] &= ~blk
    s.passable_bits, s.targets_bits = B.pack(s.passable), B.pack(s.targets)
    return s


if __name__ == "__main__":
    first, last, mode = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    if mode == "cheat":
        B.Belief.snapshot = knowing_the_map
    t = time.time()
    ev = evaluate(CFG, make_policy("chain-plan", CFG), 0, last - first, first_episode=first)
    print(json.dumps({"mode": mode, "el": ev.elratio.tolist(),
                      "mean": float(ev.elratio.mean()), "s": time.time() - t}))
