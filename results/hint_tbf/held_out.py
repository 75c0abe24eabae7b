"""The fine-tuned network (`train.sh` here) on the held-out episodes, paired with its start
(`results/hint_tb/hint_tb_full_checkpoint.pt`) and `team-beam` on the same episodes. The start's
and `team-beam`'s per-episode figures are `results/hint_tb/`'s (`full_search.py` saved them as
runs/full_net.npy, runs/full_tb.npy for seed 0; `replicate.py` as runs/rep_net.npy,
runs/rep_tb.npy for seed 1). Half the episodes on each core, then the pairing:

    .venv/bin/python results/hint_tbf/held_out.py run CKPT 0 0 500 runs/tbf_0a.npy &
    .venv/bin/python results/hint_tbf/held_out.py run CKPT 0 500 500 runs/tbf_0b.npy; wait
    .venv/bin/python results/hint_tbf/held_out.py pair CKPT 0 results/hint_tbf/held_out_seed0.json \
        runs/tbf_0a.npy runs/tbf_0b.npy runs/full_net.npy runs/full_tb.npy
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from policies import make_policy
from swarm.common.atomic import write_json
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cfg = WorldConfig()
    what, ckpt, seed = argv[0], argv[1], int(argv[2])
    if what == "run":
        first, count, out = int(argv[3]), int(argv[4]), argv[5]
        policy = make_policy("commattn", cfg, checkpoint=ckpt)
        np.save(out, evaluate(cfg, policy, seed, count, first_episode=first).elratio)
        return
    out, part_a, part_b, start_npy, tb_npy = argv[3:8]
    mine = np.concatenate([np.load(part_a), np.load(part_b)])
    start, tb = np.load(start_npy), np.load(tb_npy)
    rows = {}
    for label, theirs in (("start (hint_tb_full_checkpoint.pt)", start), ("team-beam", tb)):
        diff, se = paired(mine, theirs)
        rows[label] = {"elratio_mean": float(theirs.mean()), "mine_minus_this": diff, "se": se}
    result = {"command": "results/hint_tbf/held_out.py " + " ".join(argv), "checkpoint": ckpt,
              "episodes": f"seed {seed}, episodes 0-{len(mine) - 1}",
              "elratio_mean": float(mine.mean()), "rows": rows}
    write_json(out, result)
    print(result)


if __name__ == "__main__":
    main(sys.argv[1:])
