"""How often other policies pick `team-beam`'s action on the states CommAttn visits (the DAgger
setting of `swarm train --imitate team-beam`), including `team-beam` itself with other
tie-break noise: the ceiling of agreement a learner could reach by imitating its argmax.

    .venv/bin/python results/imitate/agreement.py 20 results/imitate/agreement_20.json

Episodes 0..K-1 of seed 0, 10 robots, shipped CommAttn driving (greedy); every receiver's
decision of every tick counts once.
"""
import json
import sys
from dataclasses import replace

from policies import make_policy
from policies.team_beam import TeamBeam
from swarm.common.atomic import write_json
from swarm.common.policy_spec import build_policy
from swarm.learn.rollout import TEACHER_SEED_STEP
from world import core
from world.config import WorldConfig
from world.decentral import batch_view

if len(sys.argv) != 3:
    sys.exit("usage: agreement.py EPISODES OUT.json")
count, path = int(sys.argv[1]), sys.argv[2]
cfg = WorldConfig()
state = core.reset(cfg, seed=0, episodes=list(range(count)))
pols = {"team-beam": TeamBeam(cfg), "team-beam, other noise": TeamBeam(cfg),
        "commattn": build_policy("commattn", cfg),
        "coordinated-frontier": make_policy("coordinated-frontier", cfg)}
for p in pols.values():
    p.reset(count)
same = {k: 0 for k in pols}
decisions = 0
while not state.done:
    view = batch_view(cfg, state)
    # the other draw sees the view as `--imitate-samples` draw 1 does: its seed moved, so only
    # the beam's tie-break noise differs
    acts = {k: p.act(replace(view, seed=view.seed + TEACHER_SEED_STEP) if "other" in k else view)
            for k, p in pols.items()}
    for k in pols:
        same[k] += int((acts[k] == acts["team-beam"])[view.receivers].sum())
    decisions += int(view.receivers.sum())
    core.step(cfg, state, acts["commattn"])
out = {"agree_with_team_beam": {k: v / decisions for k, v in same.items()},
       "decisions": decisions, "command": "results/imitate/agreement.py " + " ".join(sys.argv[1:])}
write_json(path, out)
print(json.dumps(out, indent=1))
