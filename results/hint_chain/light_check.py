"""The fine-tuned checkpoint (argument; default runs/hcp_e1.pt, a copy after epoch 1) against its
start (`hint_tb_checkpoint.pt` with the chain-plan hint and a prior of 8), both handed the light
hint they trained with (beam 8, one pass), paired on episodes 0-49 of seed 0:

    .venv/bin/python results/hint_chain/light_check.py runs/hcp_e1.pt
"""

import sys

import torch

from policies import make_policy
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

START = "results/hint_tb/hint_tb_checkpoint.pt"


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cfg = WorldConfig()
    tuned = argv[0] if argv else "runs/hcp_e1.pt"
    out = {}
    for name, ckpt in (("start", START), ("tuned", tuned)):
        policy = make_policy("commattn", cfg, checkpoint=ckpt)
        if ckpt == START:  # (the fine-tuned checkpoint has both already)
            policy.set_model(hint_planner="chain-plan", hint_prior=8.0)
        policy.set_model(hint_beam=8, hint_passes=1)
        out[name] = evaluate(cfg, policy, 0, 50).elratio
        print(name, out[name].mean(), flush=True)
    diff, se = paired(out["tuned"], out["start"])
    print(f"tuned - start (light hint): {diff:+.4f} +- {se:.4f}")


if __name__ == "__main__":
    main(sys.argv[1:])
