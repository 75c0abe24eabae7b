"""A belief CommAttn (stage B by default) against the shipped learned policies and coordinated
frontier, paired on episodes 0..999 of seed 0 (`team-beam`'s figure is in results/planners/).
Usage:

    .venv/bin/python results/belief/versus.py results/belief/versus_1000.json
    .venv/bin/python results/belief/versus.py results/belief/versus_big_1000.json \
        results/belief/belief_big_checkpoint.pt

More opponents follow the checkpoint as NAME or NAME=CHECKPOINT (e.g. team-beam, or
commattn=results/hint/hint_checkpoint.pt); each is evaluated on the same episodes.
"""

from __future__ import annotations

import sys

import torch

from policies import make_policy
from swarm.common.atomic import write_json
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

OTHERS = {"commattn (shipped)": ("commattn", "checkpoints/commattn.pt"),
          "commnet": ("commnet", "checkpoints/commnet.pt"),
          "coordinated-frontier": ("coordinated-frontier", None)}


def main(out: str, ckpt: str = "results/belief/belief_b_checkpoint.pt", *more: str) -> None:
    torch.set_num_threads(1)
    world = WorldConfig()
    mine = evaluate(world, make_policy("commattn", world, checkpoint=ckpt), 0, 1000).elratio
    rows = {}
    others = dict(OTHERS)
    for spec in more:
        name, _, path = spec.partition("=")
        others[spec] = (name, path or None)
    for label, (name, path) in others.items():
        kw = {"checkpoint": path} if path else {}
        theirs = evaluate(world, make_policy(name, world, **kw), 0, 1000).elratio
        diff, se = paired(mine, theirs)
        rows[label] = {"elratio_mean": float(theirs.mean()), "belief_minus_this": diff, "se": se}
        print(label, rows[label], flush=True)
    write_json(out, {"command": " ".join(["results/belief/versus.py", out, ckpt, *more]),
                     "checkpoint": ckpt,
                     "elratio_mean": float(mine.mean()), "rows": rows})


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(*sys.argv[1:])
