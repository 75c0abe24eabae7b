"""Issue 17: are `central`'s search weights (policies.central.CentralConfig, shared by `team-beam`
and the `team-beam` hint) worth tuning? One weight at a time, then a few combinations, each
paired with the defaults on episodes 0..399 of seed 9 (a tuning seed: not the held-out seeds 0
and 1). From the repository root (~30 s a variant on one core):

    .venv/bin/python results/planners/central_sweep.py results/planners/central_sweep.json

Found (central_sweep.json): nothing beyond noise. The best variants are +0.0015-0.0019 ± 0.0009
(lam 0.3 or 0.15, spread 1), and combining them gives less (+0.0007-0.0011); a wider beam,
horizons 5 and 7, gamma 0.9 and 0.995, crowd 0.25 and 1.0 change nothing or lose. Over 20
variants, 2 standard errors is what the best of them shows by chance, so the defaults stay.
"""

from __future__ import annotations

import sys

import torch

from policies.central import CentralConfig, CentralPolicy
from swarm.common.atomic import write_json
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

SEED, EPISODES = 9, 400
VARIANTS = [dict(lam=0.3), dict(lam=1.0), dict(lam=1.5), dict(crowd=0.25), dict(crowd=1.0),
            dict(gamma=0.9), dict(gamma=0.995), dict(spread=1), dict(spread=3), dict(beam=48),
            dict(passes=3), dict(horizon=5), dict(horizon=7), dict(lam=0.3, spread=1),
            dict(lam=0.15), dict(lam=0.0), dict(spread=0), dict(lam=0.3, spread=1, passes=3),
            dict(lam=0.15, spread=1), dict(lam=0.3, spread=1, horizon=7)]


def main(out: str) -> None:
    torch.set_num_threads(1)
    cfg = WorldConfig()
    base = evaluate(cfg, CentralPolicy(cfg), SEED, EPISODES).elratio
    rows = []
    for v in VARIANTS:
        e = evaluate(cfg, CentralPolicy(cfg, CentralConfig(**v)), SEED, EPISODES).elratio
        diff, se = paired(e, base)
        rows.append({"change": v, "elratio": float(e.mean()), "minus_default": diff, "se": se})
        print(rows[-1], flush=True)
    write_json(out, {"command": f"results/planners/central_sweep.py {out}",
                     "episodes": f"seed {SEED}, episodes 0-{EPISODES - 1}",
                     "default": float(base.mean()), "rows": rows})


if __name__ == "__main__":
    main(*sys.argv[1:])
