"""A second, independent held-out set for the claim of `full_search_1000.json`: the
`team-beam`-hint network with the full search's hint (`hint_tb_full_checkpoint.pt`) paired with
`team-beam` on episodes 0..999 of SEED (the first measurement used seed 0). Two processes (one
per core), then the pairing, from the repository root:

    .venv/bin/python results/hint_tb/replicate.py net 1 runs/rep_net.npy &
    .venv/bin/python results/hint_tb/replicate.py team-beam 1 runs/rep_tb.npy; wait
    .venv/bin/python results/hint_tb/replicate.py pair 1 runs/rep_net.npy runs/rep_tb.npy \\
        results/hint_tb/replicate_seed1.json

`pair` also pools the two sets (2000 episodes) with `full_search.py`'s arrays if they are given
after the output file (`runs/full_net.npy runs/full_tb.npy`). `others` pairs a saved array of the
network with the shipped CommAttn, CommNet and coordinated frontier on the same episodes:

    .venv/bin/python results/hint_tb/replicate.py others 1 runs/rep_net.npy \
        results/hint_tb/others_seed1.json
    .venv/bin/python results/hint_tb/replicate.py others 0 runs/full_net.npy \
        results/hint_tb/others_seed0.json
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

CKPT = "results/hint_tb/hint_tb_full_checkpoint.pt"
OTHERS = {"commattn (shipped)": ("commattn", "checkpoints/commattn.pt"),
          "commnet": ("commnet", "checkpoints/commnet.pt"),
          "coordinated-frontier": ("coordinated-frontier", None)}


def others(seed: int, net_npy: str, out: str) -> None:
    """The network's saved elratios paired with each of OTHERS on the same episodes."""
    cfg, net = WorldConfig(), np.load(net_npy)
    rows = {}
    for label, (name, path) in OTHERS.items():
        kw = {"checkpoint": path} if path else {}
        theirs = evaluate(cfg, make_policy(name, cfg, **kw), seed, len(net)).elratio
        diff, se = paired(net, theirs)
        rows[label] = {"elratio_mean": float(theirs.mean()), "net_minus_this": diff, "se": se}
        print(label, rows[label], flush=True)
    write_json(out, {"command": f"results/hint_tb/replicate.py others {seed} {net_npy} {out}",
                     "episodes": f"seed {seed}, episodes 0-{len(net) - 1}", "checkpoint": CKPT,
                     "net_full_hint": float(net.mean()), "rows": rows})


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cfg = WorldConfig()
    what, seed = argv[0], int(argv[1])
    if what == "others":
        others(seed, argv[2], argv[3])
        return
    if what == "pair":
        net, tb = np.load(argv[2]), np.load(argv[3])
        diff, se = paired(net, tb)
        out = {"command": "results/hint_tb/replicate.py " + " ".join(argv),
               "episodes": f"seed {seed}, episodes 0-{len(net) - 1}", "checkpoint": CKPT,
               "net_full_hint": float(net.mean()), "team_beam": float(tb.mean()),
               "net_minus_team_beam": diff, "se": se}
        if len(argv) > 5:  # pooled with another seed's arrays
            net2, tb2 = np.load(argv[5]), np.load(argv[6])
            pooled, pooled_se = paired(np.concatenate([net, net2]), np.concatenate([tb, tb2]))
            out["pooled"] = {"episodes": len(net) + len(net2), "net_minus_team_beam": pooled,
                             "se": pooled_se, "with": [argv[5], argv[6]]}
        write_json(argv[4], out)
        print(out)
        return
    policy = (make_policy("commattn", cfg, checkpoint=CKPT) if what == "net"
              else make_policy("team-beam", cfg))
    np.save(argv[2], evaluate(cfg, policy, seed, 1000).elratio)


if __name__ == "__main__":
    main(sys.argv[1:])
