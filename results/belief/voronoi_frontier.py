"""Would a robot's own share of the frontier help? (issue 17, a lever tried and dropped)

`VoronoiFrontier`: nearest frontier restricted to the receiver's share of the targets, those
no robot it hears this tick reaches (through its belief) in fewer steps than it does; all
targets when its share is empty. A results script, not a policy of the registry. It plays
the held-out episodes beside nearest frontier and coordinated frontier, paired:

    .venv/bin/python results/belief/voronoi_frontier.py results/belief/voronoi_frontier_1000.json

The learned twin (the same share as a third belief window of CommAttn) lives on the
`voronoi` branch; its measurement is in results/belief/README.md.
"""

from __future__ import annotations

import json
import sys

import numpy as np

from policies import make_policy
from policies.belief import Snapshot
from policies.grid_search import UNREACHED, cell_bits, distance_fields, pack, steps_toward
from policies.nearest_frontier import NearestFrontier
from swarm.common.atomic import write_json
from swarm.common.report import paired
from swarm.learn.evaluate import evaluate
from world.config import WorldConfig
from world.decentral import View

EPISODES, SEED = 1000, 0


class VoronoiFrontier(NearestFrontier):
    """Nearest frontier over the receiver's share of the targets (ties go to both robots)."""

    name = "voronoi-frontier"

    def first_moves(self, view: View, snap: Snapshot) -> np.ndarray:
        h, w = self.cfg.height, self.cfg.width
        r, words = snap.size, snap.passable_bits.shape[2]
        me = distance_fields(snap.passable_bits, cell_bits(snap.cells, h, words), w)
        others = view.hears[snap.g, snap.i] & view.msgs.present[snap.g]
        others[np.arange(r), snap.i] = False
        rr, jj = np.nonzero(others)
        src = np.zeros((r, h, w), dtype=bool)
        pos = view.msgs.pos[snap.g[rr], jj]
        src[rr, pos[:, 0], pos[:, 1]] = True
        them = distance_fields(snap.passable_bits, pack(src), w)
        mine = snap.targets & (me != UNREACHED) & (me <= them)
        share = np.where(mine.any(axis=(1, 2))[:, None, None], pack(mine), snap.targets_bits)
        return steps_toward(snap.passable_bits, share, snap.cells)[1]


def main(out: str) -> None:
    world = WorldConfig()
    rows, first = [], None
    for name, policy in [("voronoi-frontier", VoronoiFrontier(world)),
                         ("nearest-frontier", make_policy("nearest-frontier", world)),
                         ("coordinated-frontier", make_policy("coordinated-frontier", world))]:
        res = evaluate(world, policy, SEED, EPISODES)
        row = {"name": name, "episodes": EPISODES, "seed": SEED,
               "elratio_mean": float(res.elratio.mean()),
               "success_rate": float(res.success.mean()),
               "collisions_mean": float(res.collisions.mean())}
        if first is None:
            first = res.elratio
        else:
            row["voronoi_minus"], row["voronoi_minus_se"] = paired(first, res.elratio)
        rows.append(row)
        print(json.dumps(row), flush=True)
    write_json(out, {"rows": rows})


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: voronoi_frontier.py OUT.json")
    main(sys.argv[1])
