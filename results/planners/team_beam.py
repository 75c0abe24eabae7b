"""`team-beam` (policies/team_beam.py: `central`'s planner run by every robot alone) on held-out
episodes of seed 0, with the shipped CommAttn, coordinated frontier and `central` on the same
episodes, paired differences against CommAttn:

    .venv/bin/python results/planners/team_beam.py 1000 results/planners/team_beam_1000.json
"""
import json
import sys
import time

import numpy as np

from swarm.common.atomic import write_json
from swarm.common.policy_spec import build_policy
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

if len(sys.argv) != 3:
    sys.exit("usage: team_beam.py EPISODES OUT.json")
count, path = int(sys.argv[1]), sys.argv[2]
cfg = WorldConfig()
el, out = {}, {"episodes": f"seed 0, episodes 0-{count - 1}", "rows": {}, "seconds": {}}
for name in ("team-beam", "commattn", "coordinated-frontier", "central"):
    t0 = time.time()
    res = evaluate(cfg, build_policy(name, cfg), 0, count, batch=min(count, 100))
    out["seconds"][name] = time.time() - t0
    el[name] = res.elratio
    row = {"elratio": float(res.elratio.mean()),
           "se": float(res.elratio.std(ddof=1) / np.sqrt(count)),
           "success": float(res.success.mean()),
           "collisions": float(res.collisions.mean())}
    if name != "commattn" and "commattn" in el:
        row["minus_commattn"], row["minus_commattn_se"] = paired(res.elratio, el["commattn"])
    out["rows"][name] = row
    print(name, json.dumps(row), f"{out['seconds'][name]:.0f} s", flush=True)
d, se = paired(el["team-beam"], el["commattn"])
out["rows"]["team-beam"]["minus_commattn"], out["rows"]["team-beam"]["minus_commattn_se"] = d, se
out["command"] = "results/planners/team_beam.py " + " ".join(sys.argv[1:])
write_json(path, out)
