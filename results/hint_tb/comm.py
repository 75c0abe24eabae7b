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
import time

import torch

from swarm.common.atomic import write_json
from swarm.common.policy_spec import build_policy
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from swarm.net.faults import plan_from_table
from swarm.studies.comm import CONDITIONS
from world.config import WorldConfig, replace

EPISODES, SEED = 200, 0
CKPT = "results/hint_tb/hint_tb_full_checkpoint.pt"
OTHERS = ("team-beam", "commattn", "coordinated-frontier")
if len(sys.argv) < 3:
    sys.exit("usage: comm.py OUT.json I [I ...]")
torch.set_num_threads(1)
path, picks = sys.argv[1], [int(a) for a in sys.argv[2:]]
base = WorldConfig()
rows = []
for k in picks:
    label, changes, faults = CONDITIONS[k]
    if "height" in changes:
        sys.exit(f"condition {k} ({label}) is not on 20 x 20")
    wc = replace(base, **changes)
    el = {}
    t0 = time.time()
    for name in ("hint", *OTHERS):
        plan = plan_from_table({**faults, "seed": SEED}, SEED) if faults else None
        policy = build_policy("commattn", wc, CKPT) if name == "hint" else build_policy(name, wc)
        el[name] = evaluate(wc, policy, SEED, EPISODES, batch=100, faults=plan, tick_s=2.0)
    row = {"condition": label, "episodes": EPISODES, "seconds": time.time() - t0}
    for name, res in el.items():
        row[name] = {"elratio": float(res.elratio.mean()), "success": float(res.success.mean())}
    for other in OTHERS:
        row[f"hint_minus_{other}"] = paired(el["hint"].elratio, el[other].elratio)
    rows.append(row)
    print(json.dumps(row), flush=True)
write_json(path, {"rows": rows, "checkpoint": CKPT,
                  "command": "results/hint_tb/comm.py " + " ".join(sys.argv[1:])})
