"""Issue 17: does the hint network follow a stronger planner at test time? The full-search hint
network (`hint_tb_full_checkpoint.pt`, trained reading `team-beam`'s hint) handed, instead,
the decentralized whole-horizon re-planner's move (`results/planners/replan.py`'s
`DecentralizedReplan` with ITERS local-search rounds and beam BEAM: 0.9434 alone on these
episodes at 2 and 16, `results/planners/replan_light_2_16.json`). From the repository root:

    .venv/bin/python results/hint_tb/replan_hint.py 2 16 20 results/hint_tb/replan_hint_2_16.json
    .venv/bin/python results/hint_tb/replan_hint.py chain 4 32 0 16 20 \
        results/hint_tb/chain_hint_4_32.json   # `chain-plan`'s move as the hint [--cold]

Found (episodes 0-19 of seed 0, ~5.9 s an episode): 0.9389, -0.0045 +- 0.0041 below the
re-planner it reads and +0.0035 +- 0.0046 above the same network reading `team-beam`'s full
search (`runs/full_net.npy`, from `full_search.py`): a network trained on one planner's hint
does not carry a stronger planner's lead over; training it on this hint would cost ~6 s an
episode (~16 h for the 9,600 episodes of the last fine-tune on this machine).
"""
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "planners"))
import replan  # noqa: E402  results/planners/replan.py

from policies import make_policy  # noqa: E402
from policies.belief import Snapshot  # noqa: E402
from policies.chain_plan import ChainConfig, ChainPlan  # noqa: E402
from swarm.common.atomic import write_json  # noqa: E402
from swarm.common.report import paired  # noqa: E402
from swarm.learn.evaluate import evaluate  # noqa: E402
from world.config import WorldConfig  # noqa: E402
from world.decentral import View  # noqa: E402

CKPT = "results/hint_tb/hint_tb_full_checkpoint.pt"


class ReplanHint:
    """The re-planner's move as the network's hint (the Featurizer's `hint.first_moves`)."""

    def __init__(self, moves: Callable[[View, Snapshot], np.ndarray]) -> None:
        self.moves = moves  # (view, snapshot) -> each receiver's move [R]

    def first_moves(self, view: View, snap: Snapshot) -> np.ndarray:
        out = np.zeros((snap.size, 9), dtype=bool)
        out[np.arange(snap.size), self.moves(view, snap)] = True
        return out


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cfg = WorldConfig()
    chain = argv[0] == "chain"
    if chain:  # `chain-plan`'s move (policies/chain_plan.py): alone, it is measured here too
        search, (n, out) = [int(a) for a in argv[1:5]], (int(argv[5]), argv[6])
        chain_cfg = ChainConfig(*search, warm="--cold" not in argv)
        alone = evaluate(cfg, ChainPlan(cfg, chain_cfg), 0, n, batch=n).elratio
        hint = ReplanHint(ChainPlan(cfg, chain_cfg).moves)
    else:
        search, (n, out) = [int(argv[0]), int(argv[1])], (int(argv[2]), argv[3])
        replan.ITERS, replan.BEAM = search
        alone = np.array(json.loads(Path(f"results/planners/replan_light_{argv[0]}_{argv[1]}.json")
                                    .read_text())["per_episode"])[:n]
        hint = ReplanHint(lambda view, snap: replan.own_moves(cfg, view, snap))
    net = make_policy("commattn", cfg, checkpoint=CKPT)
    net.features.hint = hint
    t0 = time.time()
    mine = evaluate(cfg, net, 0, n, batch=n).elratio
    seconds = (time.time() - t0) / n
    diff, se = paired(mine, alone)
    result = {"command": "results/hint_tb/replan_hint.py " + " ".join(argv),
              "episodes": f"seed 0, episodes 0-{n - 1}", "checkpoint": CKPT,
              "planner": "chain" if chain else "replan", "search": search,
              "elratio": float(mine.mean()), "seconds_per_episode": seconds,
              "planner_alone": float(alone.mean()), "minus_planner_alone": diff, "se": se,
              "per_episode": mine.tolist(), "planner_per_episode": alone.tolist()}
    full = Path("runs/full_net.npy")  # the same network with its own hint (full_search.py)
    if full.exists():
        d, e = paired(mine, np.load(full)[:n])
        result["minus_team_beam_full_hint"], result["se_team_beam_full_hint"] = d, e
    write_json(out, result)
    print({k: v for k, v in result.items() if k != "per_episode"})


if __name__ == "__main__":
    main(sys.argv[1:])
