"""The network fine-tuned on `chain-plan`'s hint (`train.sh` here) on held-out episodes, handed
`chain-plan`'s own search as its hint (model hint_beam 32, hint_passes 4: ChainConfig() exactly;
it trained with the light one, 8 and 1), paired on the same episodes with every policy of
`results/planners/chain_plan_1000.json` (seed 0, episodes 0-999). Half the episodes on each
core, then the pairing:

    .venv/bin/python results/hint_chain/held_out.py run CKPT 0 0 500 runs/hc_a.npy &
    .venv/bin/python results/hint_chain/held_out.py run CKPT 0 500 500 runs/hc_b.npy; wait
    .venv/bin/python results/hint_chain/held_out.py pair CKPT results/hint_chain/held_out.json \
        runs/hc_a.npy runs/hc_b.npy

`run ... BEAM PASSES` sets another hint search (8 1: the light one it trained with).
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

OTHERS = "results/planners/chain_plan_1000.json"


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cfg = WorldConfig()
    what, ckpt = argv[0], argv[1]
    if what == "run":
        seed, first, count, out = int(argv[2]), int(argv[3]), int(argv[4]), argv[5]
        beam, passes = (int(argv[6]), int(argv[7])) if len(argv) > 7 else (32, 4)
        policy = make_policy("commattn", cfg, checkpoint=ckpt)
        policy.set_model(hint_beam=beam, hint_passes=passes)
        res = evaluate(cfg, policy, seed, count, first_episode=first)
        np.save(out, np.stack([res.elratio, res.success.astype(np.float64)]))
        return
    out, parts = argv[2], argv[3:]
    mine, success = np.concatenate([np.load(p) for p in parts], axis=1)
    others = json.load(open(OTHERS))["per_episode"]
    rows = {}
    for label, theirs in others.items():
        theirs = np.asarray(theirs, dtype=np.float64)[:len(mine)]
        diff, se = paired(mine, theirs)
        rows[label] = {"elratio_mean": float(theirs.mean()), "mine_minus_this": diff, "se": se}
    result = {"command": "results/hint_chain/held_out.py " + " ".join(argv), "checkpoint": ckpt,
              "episodes": f"seed 0, episodes 0-{len(mine) - 1}", "elratio_mean": float(mine.mean()),
              "success": float(success.mean()), "rows": rows,
              "per_episode": mine.tolist()}
    write_json(out, result)
    print(json.dumps({k: v for k, v in result.items() if k != "per_episode"}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
