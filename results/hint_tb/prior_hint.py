"""Issue 17: the hint network as a residual on `chain-plan`. The full-search hint network
(`hint_tb_full_checkpoint.pt`) reads `chain-plan`'s move as its hint (as `replan_hint.py chain`)
and acts greedily on its logits plus BETA on the hinted move: BETA 0 is the network alone, a
large BETA is `chain-plan` itself; in between the network deviates from the plan only where it
prefers another move by more than BETA. Does any BETA beat the planner? From the repository
root (~2.6 s an episode a BETA on one core):

    .venv/bin/python results/hint_tb/prior_hint.py 50 results/hint_tb/prior_hint.json 0 1 3 8

Found (episodes 0-49 of seed 0): no. The score rises with BETA to `chain-plan`'s own (see the
JSON and results/hint_tb/README.md): every deviation the network keeps costs on average.
"""
import sys
import time
from pathlib import Path

import numpy as np
import torch

import policies.infer.policy as inference
from policies import make_policy
from policies.chain_plan import ChainConfig, ChainPlan
from swarm.common.atomic import write_json
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))
from replan_hint import CKPT, ReplanHint  # noqa: E402  results/hint_tb/replan_hint.py


class KeepHint:
    """The network's featurizer, keeping the hint columns (one-hot, last 9 of the own
    features) of the rows it made for the chooser."""

    def __init__(self, features) -> None:
        self.features, self.hint = features, np.zeros((0, 9))

    def __getattr__(self, name: str):
        return getattr(self.features, name)

    def __call__(self, view):
        tokens = self.features(view)
        self.hint = tokens.own_feats[:, -9:].astype(np.float64)
        return tokens


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    n, out, betas = int(argv[0]), argv[1], [float(b) for b in argv[2:]]
    cfg = WorldConfig()
    search = ChainConfig()  # the shipped chain-plan (warm heads, 4 rounds, beam 32)
    alone = evaluate(cfg, ChainPlan(cfg, search), 0, n, batch=n).elratio
    net = make_policy("commattn", cfg, checkpoint=CKPT)
    net.features.hint = ReplanHint(ChainPlan(cfg, search).moves)
    kept = net.features = KeepHint(net.features)
    rows = []
    for beta in betas:  # greedy: argmax of the logits plus beta on the hinted move
        inference.chooser = lambda noise, b=beta: (
            lambda r, logits: (logits.astype(np.float64) + b * kept.hint[r]).argmax(-1))
        t0 = time.time()
        mine = evaluate(cfg, net, 0, n, batch=n).elratio
        diff, se = paired(mine, alone)
        rows.append({"beta": beta, "elratio": float(mine.mean()), "minus_chain_plan": diff,
                     "se": se, "seconds_per_episode": (time.time() - t0) / n,
                     "per_episode": mine.tolist()})
        print({k: v for k, v in rows[-1].items() if k != "per_episode"}, flush=True)
    write_json(out, {"command": "results/hint_tb/prior_hint.py " + " ".join(argv),
                     "episodes": f"seed 0, episodes 0-{n - 1}", "checkpoint": CKPT,
                     "chain_plan": float(alone.mean()), "chain_plan_per_episode": alone.tolist(),
                     "rows": rows})


if __name__ == "__main__":
    main(sys.argv[1:])
