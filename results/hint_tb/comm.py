"""The best learned policy (`hint_tb_full_checkpoint.pt`: CommAttn reading `team-beam`'s full
search as its hint) under `swarm repro comm`'s scarce-communication conditions on 20 x 20 (the
same conditions, seed and 200 episodes as `results/repro/comm.md` and
`results/planners/team_beam_comm.py`), with `team-beam`, the shipped CommAttn and coordinated
frontier re-run on the same episodes for paired differences. Where does the learned part pay,
and where does it inherit its planner's losses?

    .venv/bin/python results/hint_tb/comm.py OUT.json I [I ...]

I: indices into `swarm.studies.comm.CONDITIONS` (0-8 are the 20 x 20 ones; ~315 s a condition
on one core, the network and `team-beam` most of it). The README's table is `comm_a.json`
(0-4) and `comm_b.json` (5-8).
"""
import json
import sys

import torch

from swarm.common.atomic import write_json
from swarm.studies.comm import CONDITIONS, paired_conditions

EPISODES, SEED = 200, 0
CKPT = "results/hint_tb/hint_tb_full_checkpoint.pt"
SPECS = {"hint": ("commattn", CKPT), "team-beam": ("team-beam", None),
         "commattn": ("commattn", None), "coordinated-frontier": ("coordinated-frontier", None)}
if len(sys.argv) < 3:
    sys.exit("usage: comm.py OUT.json I [I ...]")
torch.set_num_threads(1)
path, picks = sys.argv[1], [int(a) for a in sys.argv[2:]]
for k in picks:
    if "height" in CONDITIONS[k][1]:
        sys.exit(f"condition {k} ({CONDITIONS[k][0]}) is not on 20 x 20")
rows = paired_conditions(picks, SPECS, SEED, EPISODES)
for row in rows:
    print(json.dumps(row), flush=True)
write_json(path, {"rows": rows,
                  "checkpoint": CKPT,
                  "command": "results/hint_tb/comm.py " + " ".join(sys.argv[1:])})
