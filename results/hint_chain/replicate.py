"""A second, independent held-out set for `prior16_1000.json`'s tie: the prior-16 network
(`chain_prior16_checkpoint.pt`, its hint `chain-plan`'s own search) paired with `chain-plan` on
episodes FIRST..FIRST+COUNT-1 of SEED (the first measurement used seed 0, episodes 0-999). One
process per policy (one per core), then the pairing, from the repository root:

    .venv/bin/python results/hint_chain/replicate.py net 1 0 300 runs/rep_net.npy &
    .venv/bin/python results/hint_chain/replicate.py chain-plan 1 0 300 runs/rep_plan.npy; wait
    .venv/bin/python results/hint_chain/replicate.py pair results/hint_chain/replicate_seed1.json \\
        runs/rep_net.npy runs/rep_plan.npy
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
from world.config import WorldConfig

CKPT = "results/hint_chain/chain_prior16_checkpoint.pt"


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cfg = WorldConfig()
    if argv[0] == "pair":
        out, net_npy, plan_npy = argv[1:4]
        net, plan = np.load(net_npy), np.load(plan_npy)
        meta = json.loads(open(net_npy + ".json").read())
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
    policy = (make_policy("commattn", cfg, checkpoint=CKPT) if what == "net"
              else make_policy(what, cfg))
    res = evaluate(cfg, policy, seed, count, first_episode=first)
    np.save(out, np.stack([res.elratio, res.success.astype(np.float64)]))
    with open(out + ".json", "w") as f:
        json.dump({"episodes": f"seed {seed}, episodes {first}-{first + count - 1}"}, f)


if __name__ == "__main__":
    main(sys.argv[1:])
