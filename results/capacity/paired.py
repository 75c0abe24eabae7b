"""Paired held-out comparison of CommAttn checkpoints on the same episodes (issue 17's
"larger networks" lever). Usage, from the repository root:

    .venv/bin/python results/capacity/paired.py OUT.json NAME=CHECKPOINT NAME=CHECKPOINT ...

Every checkpoint plays episodes 0..999 of seed 0 (the held-out evaluation seeds, as `swarm
eval --seed 0`); the first one is the reference of the paired differences.
"""

from __future__ import annotations

import json
import sys

from policies import make_policy
from swarm.common.atomic import write_json
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

EPISODES, SEED = 1000, 0


def main(out: str, named: list[str]) -> None:
    world = WorldConfig()
    rows, first = [], None
    if not named or any("=" not in item for item in named):
        sys.exit("usage: paired.py OUT.json NAME=CHECKPOINT [NAME=CHECKPOINT ...]")
    for item in named:
        name, path = item.split("=", 1)
        res = evaluate(world, make_policy("commattn", world, checkpoint=path), SEED, EPISODES)
        row = {"name": name, "checkpoint": path, "episodes": EPISODES, "seed": SEED,
               "elratio_mean": float(res.elratio.mean()),
               "success_rate": float(res.success.mean())}
        if first is None:
            first = res.elratio
        else:
            row["minus_first"], row["minus_first_se"] = paired(res.elratio, first)
        rows.append(row)
        print(json.dumps(row))
    write_json(out, {"command": " ".join(["results/capacity/paired.py", out, *named]),
                     "rows": rows})


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "", sys.argv[2:])
