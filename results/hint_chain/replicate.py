"""A second, independent held-out set for `prior16_1000.json`'s tie: the prior-16 network
(`chain_prior16_checkpoint.pt`, its hint `chain-plan`'s own search) paired with `chain-plan` on
episodes FIRST..FIRST+COUNT-1 of SEED (the first measurement used seed 0, episodes 0-999). One
process per policy (one per core), then the pairing, from the repository root:

    .venv/bin/python results/hint_chain/replicate.py net 1 0 300 runs/rep_net.npy &
    .venv/bin/python results/hint_chain/replicate.py chain-plan 1 0 300 runs/rep_plan.npy; wait
    .venv/bin/python results/hint_chain/replicate.py pair results/hint_chain/replicate_seed1.json \\
        runs/rep_net.npy runs/rep_plan.npy

A sixth argument I runs under `swarm repro comm`'s condition I (`swarm.studies.comm.CONDITIONS`:
its world and `[faults]`, the fault draws seeded by SEED as there), e.g. range 5 on episodes
100-399 of seed 0, past the 100 of `comm_pair_a.json` (`range5_100_400.json`); `pair` takes
NET PLAN pairs, concatenated:

    .venv/bin/python results/hint_chain/replicate.py net 0 100 150 runs/r5_net_a.npy 1 & ...
"""

from __future__ import annotations

import json
import sys

import numpy as np
import torch

from policies import make_policy
from swarm.common.atomic import write_json
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from swarm.net.faults import plan_from_table
from swarm.studies.comm import CONDITIONS
from world.config import WorldConfig, replace

CKPT = "results/hint_chain/chain_prior16_checkpoint.pt"


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cfg = WorldConfig()
    if argv[0] == "pair":
        out, nets, plans = argv[1], argv[2::2], argv[3::2]  # NET PLAN [NET PLAN ...]
        net = np.concatenate([np.load(f) for f in nets], axis=1)
        plan = np.concatenate([np.load(f) for f in plans], axis=1)
        meta = {"episodes": "; ".join(json.loads(open(f + ".json").read())["episodes"]
                                      for f in nets)}
        diff, se = paired(net[0], plan[0])
        result = {"command": "results/hint_chain/replicate.py " + " ".join(argv),
                  "checkpoint": CKPT, "episodes": meta["episodes"],
                  "net": {"elratio_mean": float(net[0].mean()), "success": float(net[1].mean())},
                  "chain-plan": {"elratio_mean": float(plan[0].mean()),
                                 "success": float(plan[1].mean())},
                  "net_minus_chain_plan": diff, "se": se,
                  "per_episode": {"net": net[0].tolist(), "chain-plan": plan[0].tolist()}}
        write_json(out, result)
        print(json.dumps({k: v for k, v in result.items() if k != "per_episode"}, indent=1))
        return
    what, seed, first, count, out = argv[0], int(argv[1]), int(argv[2]), int(argv[3]), argv[4]
    plan, where = None, ""
    if len(argv) > 5:
        label, changes, faults = CONDITIONS[int(argv[5])]
        cfg, where = replace(cfg, **changes), f", condition {label!r}"
        plan = plan_from_table({**faults, "seed": seed}, seed) if faults else None
    policy = (make_policy("commattn", cfg, checkpoint=CKPT) if what == "net"
              else make_policy(what, cfg))
    res = evaluate(cfg, policy, seed, count, first_episode=first, faults=plan)
    np.save(out, np.stack([res.elratio, res.success.astype(np.float64)]))
    with open(out + ".json", "w") as f:
        json.dump({"episodes": f"seed {seed}, episodes {first}-{first + count - 1}{where}"}, f)


if __name__ == "__main__":
    main(sys.argv[1:])
