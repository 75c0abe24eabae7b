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
import time

from swarm.common.atomic import write_json
from swarm.common.policy_spec import build_policy
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from swarm.net.faults import plan_from_table
from swarm.studies.comm import CONDITIONS
from world.config import WorldConfig, replace

EPISODES, SEED = 200, 0
if len(sys.argv) < 3:
    sys.exit("usage: team_beam_comm.py OUT.json I [I ...]")
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
    for name in ("team-beam", "commattn", "coordinated-frontier"):
        plan = plan_from_table({**faults, "seed": SEED}, SEED) if faults else None
        res = evaluate(wc, build_policy(name, wc), SEED, EPISODES, batch=100, faults=plan,
                       tick_s=2.0)
        el[name] = res
    row = {"condition": label, "episodes": EPISODES, "seconds": time.time() - t0}
    for name, res in el.items():
        row[name] = {"elratio": float(res.elratio.mean()), "success": float(res.success.mean())}
    for other in ("commattn", "coordinated-frontier"):
        row[f"team_beam_minus_{other}"] = paired(el["team-beam"].elratio, el[other].elratio)
    rows.append(row)
    print(json.dumps(row), flush=True)
write_json(path, {"rows": rows, "command": "results/planners/team_beam_comm.py "
                  + " ".join(sys.argv[1:])})
