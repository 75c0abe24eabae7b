"""Issue 17: `chain-plan` (policies/chain_plan.py: whole-horizon planning passed down the id
chain) on held-out episodes of seed 0, with the decentralized policies it is compared with on
the same episodes (paired differences against `chain-plan`). From the repository root:

    .venv/bin/python results/planners/chain_plan.py COUNT OUT.json \\
        [HEAD_ITERS HEAD_BEAM ITERS BEAM [--cold]] [--only]

COUNT episodes 0..COUNT-1; the four numbers are `ChainConfig`'s search (default 4 32 0 16),
`--cold`: a chain head plans from scratch every tick (no warm start); `--only`: `chain-plan`
and `team-beam` alone (the search scan).
"""
import sys
import time

import numpy as np

from policies import make_policy
from policies.chain_plan import ChainConfig, ChainPlan
from swarm.common.atomic import write_json
from swarm.common.policy_spec import build_policy
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

args = [a for a in sys.argv[1:] if not a.startswith("--")]
if len(args) not in (2, 6):
    sys.exit(__doc__)
count, path = int(args[0]), args[1]
search = ChainConfig(*(int(a) for a in args[2:6]), warm="--cold" not in sys.argv) \
    if len(args) == 6 else ChainConfig()
cfg = WorldConfig()
others = ("team-beam",) if "--only" in sys.argv else (
    "team-beam", "commattn", "commnet", "coordinated-frontier")
out = {"command": "results/planners/chain_plan.py " + " ".join(sys.argv[1:]),
       "episodes": f"seed 0, episodes 0-{count - 1}", "search": search.__dict__, "rows": {}}
el = {}
for name in ("chain-plan", *others):
    pol = ChainPlan(cfg, search) if name == "chain-plan" else (
        make_policy(name, cfg) if name == "team-beam" else build_policy(name, cfg))
    t0 = time.time()
    res = evaluate(cfg, pol, 0, count, batch=min(count, 50))
    el[name] = res.elratio
    summ = res.summary(cfg)
    row = {"elratio": float(res.elratio.mean()),
           "se": float(res.elratio.std(ddof=1) / np.sqrt(count)),
           "success": summ["success_rate"], "robot_collisions": summ["robot_collisions_mean"],
           "seconds_per_episode": (time.time() - t0) / count}
    if name != "chain-plan":
        row["minus_chain_plan"], row["se_paired"] = paired(res.elratio, el["chain-plan"])
    out["rows"][name] = row
    print(name, row, flush=True)
out["per_episode"] = {k: v.tolist() for k, v in el.items()}
write_json(path, out)
