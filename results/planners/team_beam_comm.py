"""`team-beam` under `swarm repro comm`'s scarce-communication conditions on 20 x 20 (the same
conditions, seed and episodes as `results/repro/comm.md`), with CommAttn and coordinated
frontier re-run on the same episodes for paired differences. How much a planner that depends on
what it hears loses as communication gets scarce, next to the learned policy:

    .venv/bin/python results/planners/team_beam_comm.py OUT.json I [I ...]

I: indices into `swarm.studies.comm.CONDITIONS` (the 40 x 40 ones are too slow for team-beam
here: every robot plans every robot it hears). 200 episodes of seed 0 per condition.
"""
import json
import sys

import torch

from swarm.common.atomic import write_json
from swarm.studies.comm import CONDITIONS, paired_conditions

EPISODES, SEED = 200, 0
SPECS = {"team-beam": ("team-beam", None), "commattn": ("commattn", None),
         "coordinated-frontier": ("coordinated-frontier", None)}
if len(sys.argv) < 3:
    sys.exit("usage: team_beam_comm.py OUT.json I [I ...]")
torch.set_num_threads(1)
path, picks = sys.argv[1], [int(a) for a in sys.argv[2:]]
for k in picks:
    if "height" in CONDITIONS[k][1]:
        sys.exit(f"condition {k} ({CONDITIONS[k][0]}) is not on 20 x 20")
rows = paired_conditions(picks, SPECS, SEED, EPISODES)
for row in rows:
    print(json.dumps(row), flush=True)
write_json(path, {"rows": rows,
                  "command": "results/planners/team_beam_comm.py " + " ".join(sys.argv[1:])})
