"""Issue 17: where `chain-plan`'s lost cells go. For each held-out episode (seed 0) played by
`chain-plan`, the free cells never explored at the end, split into those sealed off (no free
8-connected path from any robot at the end: a dynamic block walled them in) and those still
reachable (the team ran out of steps), and the explored cells that became dynamic blocks later
(visits that bought nothing: the block would have counted anyway). From the repository root:

    .venv/bin/python results/planners/lost_cells.py COUNT OUT.json
"""
import sys

import numpy as np

from policies.chain_plan import ChainPlan
from swarm.common.atomic import write_json
from swarm.learn.evaluate import batch_view
from world import core
from world.config import WorldConfig

if len(sys.argv) != 3:
    sys.exit(__doc__)
count, path = int(sys.argv[1]), sys.argv[2]
cfg = WorldConfig()
lay = core.Layout.of(cfg)
rows = []
for lo in range(0, count, 25):
    eps = np.arange(lo, min(lo + 25, count))
    state = core.reset(cfg, 0, eps)
    pol = ChainPlan(cfg)
    pol.reset(len(eps))
    while not state.done:
        core.step(cfg, state, pol.act(batch_view(cfg, state)))
    for b in range(len(eps)):
        g, expl = state.grid[b], state.explored[b]
        free = g == core.FREE
        reach = np.zeros(lay.size, dtype=bool)
        stack = [int(p) for p in state.pos[b]]
        reach[stack] = True
        while stack:
            c = stack.pop()
            for d in lay.deltas[1:]:
                n = c + int(d)
                if free[n] and not reach[n]:
                    reach[n] = True
                    stack.append(n)
        lost = free & ~expl
        rows.append({"episode": int(eps[b]), "elratio": float(state.elratio[b, -1]),
                     "lost": int(lost.sum()), "sealed": int((lost & ~reach).sum()),
                     "reachable": int((lost & reach).sum()),
                     "visited_then_blocked": int((expl & (g == core.DYNAMIC)).sum())})
    print(lo, flush=True)
summary = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "episode"}
summary.update({f"{k}_se": float(np.std([r[k] for r in rows], ddof=1) / np.sqrt(len(rows)))
                for k in ("lost", "sealed", "reachable", "visited_then_blocked")})
print(summary)
write_json(path, {"command": "results/planners/lost_cells.py " + " ".join(sys.argv[1:]),
                  "episodes": f"seed 0, episodes 0-{count - 1}", "summary": summary,
                  "per_episode": rows})
