"""The `team-beam`-hint network handed the full `team-beam` search's move (beam 24, two passes)
at test time, where it was trained on the light one (beam 8, one pass), paired with `team-beam`
on episodes 0..999 of seed 0. Two processes (one per core), then the pairing:

    .venv/bin/python results/hint_tb/full_search.py net runs/full_net.npy &
    .venv/bin/python results/hint_tb/full_search.py team-beam runs/full_tb.npy; wait
    .venv/bin/python results/hint_tb/full_search.py pair runs/full_net.npy runs/full_tb.npy \
        results/hint_tb/full_search_1000.json
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from policies import make_policy
from policies.team_beam import TeamBeam
from swarm.common.atomic import write_json
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

CKPT = "results/hint_tb/hint_tb_checkpoint.pt"


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cfg = WorldConfig()
    if argv[0] == "pair":
        net, tb = np.load(argv[1]), np.load(argv[2])
        diff, se = paired(net, tb)
        write_json(argv[3], {"command": "results/hint_tb/full_search.py " + " ".join(argv),
                             "episodes": "seed 0, episodes 0-999", "checkpoint": CKPT,
                             "net_full_hint": float(net.mean()), "team_beam": float(tb.mean()),
                             "net_minus_team_beam": diff, "se": se})
        print(net.mean(), tb.mean(), diff, se)
        return
    if argv[0] == "net":
        policy = make_policy("commattn", cfg, checkpoint=CKPT)
        policy.features.hint = TeamBeam(cfg)  # the full search, where training had HINT_BEAM
    else:
        policy = make_policy("team-beam", cfg)
    np.save(argv[1], evaluate(cfg, policy, 0, 1000).elratio)


if __name__ == "__main__":
    main(sys.argv[1:])
