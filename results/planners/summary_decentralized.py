"""Decentralized whole-horizon planning against the rest on episodes 0-99 of seed 0, paired:

    for a in 0 20 40 60 80; do .venv/bin/python results/planners/replan.py $a 20 \\
        results/planners/replan_decentralized_${a}_20.json --decentralized; done
    .venv/bin/python results/planners/summary_decentralized.py   # -> summary_decentralized.json
"""
import json

import numpy as np

from swarm.common.policy_spec import build_policy
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

cfg = WorldConfig()
d = np.concatenate([json.load(open(f"results/planners/replan_decentralized_{a}_20.json"))
                    ["replan-decentralized"]["elratio"] for a in range(0, 100, 20)])
r = json.load(open("results/planners/replan_0_100.json"))
runs = {"replan-decentralized": d, "replan": np.array(r["replan"]["elratio"]),
        "central": np.array(r["central"]["elratio"])}
for name in ("commattn", "coordinated-frontier"):  # shipped checkpoint for commattn
    runs[name] = evaluate(cfg, build_policy(name, cfg), 0, 100, batch=100).elratio


def se(x: np.ndarray) -> float:
    return float(x.std(ddof=1) / np.sqrt(len(x)))


out: dict = {"episodes": "seed 0, episodes 0-99"}
for k, v in runs.items():
    out[k] = {"mean": float(v.mean()), "se": se(v),
              "paired_minus_decentralized": [float(np.mean(v - d)), se(v - d)]}
    print(f"{k:22s} {v.mean():.4f} +- {se(v):.4f}  vs decentralized {np.mean(v - d):+.4f} +- "
          f"{se(v - d):.4f}")
with open("results/planners/summary_decentralized.json", "w") as fh:
    json.dump(out, fh, indent=1)
