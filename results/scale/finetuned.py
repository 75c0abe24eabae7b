"""Paired held-out comparison on 40 x 40, 20 robots, 60 steps (seed 0, 100 episodes): the
40x40 fine-tuned CommAttn against the shipped one and nearest frontier:

    .venv/bin/python results/scale/finetuned.py checkpoints/scale/commattn_40x40_n20.pt \\
        results/scale/finetuned_n20_t60.json
"""
import json
import sys

import numpy as np

from policies import make_policy
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig, scaled_blocks

cfg = WorldConfig(height=40, width=40, n_robots=20, horizon=60, **scaled_blocks(40, 40))
ckpt = sys.argv[1]
runs = {"commattn-40x40": make_policy("commattn", cfg, checkpoint=ckpt),
        "commattn (shipped)": make_policy("commattn", cfg, checkpoint="checkpoints/commattn.pt"),
        "nearest-frontier": make_policy("nearest-frontier", cfg)}
res = {k: evaluate(cfg, p, 0, 100, batch=100) for k, p in runs.items()}
out = {}
for k, r in res.items():
    s = r.summary(cfg)
    out[k] = {m: s[m] for m in ("elratio_mean", "success_rate", "block_collisions_mean")}
    print(k, {m: round(v, 4) for m, v in out[k].items()})
a = res["commattn-40x40"].elratio
for k in ("commattn (shipped)", "nearest-frontier"):
    d = a - res[k].elratio
    se = d.std(ddof=1) / np.sqrt(len(d))
    out[f"paired vs {k}"] = {"diff": float(d.mean()), "se": float(se)}
    print("paired vs", k, round(d.mean(), 4), "+-", round(se, 4))
json.dump(out, open(sys.argv[2], "w"), indent=1)
