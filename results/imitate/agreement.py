"""How often other policies pick `team-beam`'s action on the states CommAttn visits (the DAgger
setting of `swarm train --imitate team-beam`), including `team-beam` itself with other
tie-break noise: the ceiling of agreement a learner could reach by imitating its argmax.

    .venv/bin/python results/imitate/agreement.py 20 results/imitate/agreement_20.json

Episodes 0..K-1 of seed 0, 10 robots, shipped CommAttn driving (greedy); every receiver's
decision of every tick counts once.
"""
import json
import sys
from types import SimpleNamespace

from policies import make_policy
from policies.team_beam import TeamBeam
from swarm.common.atomic import write_json
from swarm.common.policy_spec import build_policy
from world import core
from world.config import WorldConfig
from world.decentral import batch_view


class OtherNoise(TeamBeam):
    """The same planner with the beam's tie-break noise drawn under another seed."""

    def plan(self, view, groups):  # type: ignore[no-untyped-def]
        other = SimpleNamespace(msgs=view.msgs, n=view.n, tick=view.tick, seed=view.seed + 777,
                                episodes=view.episodes)
        return super().plan(other, groups)


if len(sys.argv) != 3:
    sys.exit("usage: agreement.py EPISODES OUT.json")
count, path = int(sys.argv[1]), sys.argv[2]
cfg = WorldConfig()
state = core.reset(cfg, seed=0, episodes=list(range(count)))
pols = {"team-beam": TeamBeam(cfg), "team-beam, other noise": OtherNoise(cfg),
        "commattn": build_policy("commattn", cfg),
        "coordinated-frontier": make_policy("coordinated-frontier", cfg)}
for p in pols.values():
    p.reset(count)
same = {k: 0 for k in pols}
decisions = 0
while not state.done:
    view = batch_view(cfg, state)
    acts = {k: p.act(view) for k, p in pols.items()}
    for k in pols:
        same[k] += int((acts[k] == acts["team-beam"])[view.receivers].sum())
    decisions += int(view.receivers.sum())
    core.step(cfg, state, acts["commattn"])
out = {"agree_with_team_beam": {k: v / decisions for k, v in same.items()},
       "decisions": decisions, "command": "results/imitate/agreement.py " + " ".join(sys.argv[1:])}
write_json(path, out)
print(json.dumps(out, indent=1))
