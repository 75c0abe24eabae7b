"""Summary of results/planners/replan_*.json (episodes 0-199 of seed 0) with CommAttn, coordinated
frontier and the oracle on the same episodes, paired differences with standard errors:

    .venv/bin/python results/planners/summary.py results/planners/summary.json
"""
import json
import sys

import numpy as np

from swarm.common.policy_spec import build_policy
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

cfg = WorldConfig()
parts = [json.load(open(f"results/planners/replan_{a}_100.json")) for a in (0, 100)]
el = {k: np.concatenate([p[k]["elratio"] for p in parts]) for k in ("replan", "central")}
for name in ("commattn", "coordinated-frontier", "oracle"):
    el[name] = evaluate(cfg, build_policy(name, cfg), 0, 200, batch=200).elratio  # shipped ckpt
out = {"episodes": "seed 0, episodes 0-199", "mean": {}, "se": {}, "paired_vs_replan": {}}
for k, v in el.items():
    out["mean"][k] = float(v.mean())
    out["se"][k] = float(v.std(ddof=1) / np.sqrt(len(v)))
    d = v - el["replan"]
    out["paired_vs_replan"][k] = [float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d)))]
    print(f"{k:22s} {v.mean():.4f} +- {out['se'][k]:.4f}   vs replan {d.mean():+.4f} +- "
          f"{out['paired_vs_replan'][k][1]:.4f}")
out["command"] = "results/planners/summary.py " + " ".join(sys.argv[1:])
with open(sys.argv[1], "w") as fh:
    json.dump(out, fh, indent=1)
