"""What knowing the static map is worth to `chain-plan`: the same planner whose belief holds
every static block from the start (not the dynamic blocks, not their schedule), paired with the
planner as shipped on the same held-out episodes. An upper bound for a learned map prior.

    .venv/bin/python results/planners/static_bound.py FIRST LAST base|cheat > OUT.json

prints one JSON line: per-episode elratio (seed 0, episodes FIRST..LAST-1) and the mean.
"""
import sys, json, time
import numpy as np
import torch
torch.set_num_threads(1)
from world import core
from world.config import WorldConfig
from policies import make_policy
from policies import belief as B
from swarm.learn.evaluate import evaluate

cfg = WorldConfig()
n0, n1 = int(sys.argv[1]), int(sys.argv[2])
mode = sys.argv[3]
maps = {}
def static_of(ep):
    if ep not in maps:
        maps[ep] = np.asarray(core.generate_episode(cfg, 0, int(ep))[0], bool)
    return maps[ep]
orig = B.Belief.snapshot
def cheat(self, view):
    s = orig(self, view)
    for k in range(s.size):
        st = static_of(int(view.episodes[s.g[k]]))
        unk = s.known[k] == B.UNKNOWN
        blk = unk & st
        s.known[k][blk] = B.BLOCK
        s.targets[k] &= ~blk
        s.passable[k] &= ~blk
    s.passable_bits = B.pack(s.passable); s.targets_bits = B.pack(s.targets)
    return s
if mode == "cheat":
    B.Belief.snapshot = cheat
t = time.time()
ev = evaluate(cfg, make_policy("chain-plan", cfg), 0, n1 - n0, first_episode=n0)
print(json.dumps({"mode": mode, "el": ev.elratio.tolist(), "mean": float(ev.elratio.mean()), "s": time.time() - t}))
