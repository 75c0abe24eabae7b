"""Per-episode elratio of policies on episodes 0..K-1 of seed 0 (greedy): POLICY[=CHECKPOINT[@MODE]],
MODE swapping the hint for `tbhint.TBHint(MODE)`; from the repository root:

    .venv/bin/python results/hint/tried/paired.py 200 results/hint/tried/team_beam_hint_200.json \
        "commattn=results/hint/hint_checkpoint.pt@tb" team-beam \
        "commattn=results/hint/hint_checkpoint.pt" "commattn=results/hint/hint_checkpoint.pt@and"
"""
import sys, json
import numpy as np
sys.path.insert(0, "results/hint/tried")
from swarm.common.policy_spec import build_policy
from world import core
from world.config import WorldConfig
from world.decentral import batch_view

def per_episode(cfg, policy, episodes):
    state = core.reset(cfg, 0, np.arange(episodes))
    policy.reset(episodes)
    while not state.done:
        core.step(cfg, state, policy.act(batch_view(cfg, state), greedy=True))
    return core.metrics(cfg, state).elratio.tolist()

cfg = WorldConfig()
k = int(sys.argv[1]); out = {}
for spec in sys.argv[3:]:
    name, _, rest = spec.partition("=")
    ck, _, mode = rest.partition("@")
    p = build_policy(name, cfg, ck or None)
    if mode:
        from tbhint import TBHint
        p.features.hint = TBHint(cfg, mode)
    out[spec] = per_episode(cfg, p, k)
    print(spec, np.mean(out[spec]), flush=True)
json.dump(out, open(sys.argv[2], "w"))
