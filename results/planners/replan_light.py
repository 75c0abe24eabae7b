"""Issue 17's next lever, measured small: the decentralized whole-horizon re-planner
(`replan.py --decentralized`, 0.9445 on 100 episodes but ~16 s an episode) with a lighter search,
ITERS team local-search rounds and beam BEAM per robot (replan.py: 12 and 48). Episodes 0..N-1
of seed 0, batched; from the repository root:

    .venv/bin/python results/planners/replan_light.py 2 16 20 \
        results/planners/replan_light_2_16.json

Found (20 episodes, paired on the same ones): ITERS 2, BEAM 16: 0.9434 at 5.7 s an episode
(~19 ms a robot decision), +0.0066 ± 0.0028 over `team-beam` (0.9368) and +0.0020 ± 0.0038
against the full search on the same episodes (0.9414, `replan_decentralized_0_20.json`);
ITERS 0, BEAM 16 (the beam alone): 0.9359 at 2.9-3.5 s, no better
than `team-beam`. So the team local search is what buys the lead, and a third of the full
search keeps it: a candidate hint planner (not yet built as one), too few episodes to say more.
"""
import sys
import time

import replan  # results/planners/replan.py, beside this file
import torch

from policies import make_policy
from swarm.common.atomic import write_json
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig

torch.set_num_threads(1)
iters, beam, n, out = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
replan.ITERS, replan.BEAM = iters, beam
cfg = WorldConfig()
t0 = time.time()
mine = evaluate(cfg, replan.DecentralizedReplan(cfg), 0, n, batch=n).elratio
seconds = (time.time() - t0) / n
tb = evaluate(cfg, make_policy("team-beam", cfg), 0, n).elratio
diff, se = paired(mine, tb)
result = {"command": "results/planners/replan_light.py " + " ".join(sys.argv[1:]),
          "episodes": f"seed 0, episodes 0-{n - 1}", "iters": iters, "beam": beam,
          "elratio": float(mine.mean()), "seconds_per_episode": seconds,
          "team_beam": float(tb.mean()), "minus_team_beam": diff, "se": se,
          "per_episode": mine.tolist()}
write_json(out, result)
print({k: v for k, v in result.items() if k != "per_episode"})
