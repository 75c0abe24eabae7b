"""The hint network given `team-beam`'s chosen move as its hint instead of coordinated
frontier's moves, at test time only (no training): `TBHint` replaces the Featurizer's planner.
Mode `tb`: team-beam's move alone; `and`: team-beam's move where coordinated frontier's set
contains it, else coordinated frontier's set. Run through `paired.py` (see ../README.md)."""
import sys, json
from types import SimpleNamespace
import numpy as np
sys.path.insert(0, "results/planners")
from steps import run
from swarm.common.policy_spec import build_policy
from policies.team_beam import TeamBeam
from world.config import WorldConfig
import steps

class TBHint:
    def __init__(self, cfg, mode):
        self.tb = TeamBeam(cfg); self.mode = mode
        from policies.coordinated_frontier import CoordinatedFrontier
        self.cf = CoordinatedFrontier(cfg)
    def first_moves(self, view, snap):
        g, i, r = snap.g, snap.i, snap.size
        team = view.hears[g, i] & view.msgs.present[g]
        pos = np.where(team[..., None], view.msgs.pos[g], snap.cells[:, None, :])
        sub = SimpleNamespace(msgs=SimpleNamespace(present=team, pos=pos), n=view.n,
                              tick=view.tick, seed=view.seed, episodes=np.asarray(view.episodes)[g])
        self.tb.known = snap.known.reshape(r, -1)
        self.tb.explored = snap.explored.reshape(r, -1)
        a = self.tb.plan(sub, np.arange(r))[np.arange(r), i]
        out = np.zeros((r, 9), dtype=bool)
        out[np.arange(r), a] = True
        if self.mode == "and":  # team-beam's move only where CF agrees, else CF's set
            cf = self.cf.first_moves(view, snap)
            out = np.where((out & cf).any(1, keepdims=True), out, cf)
        return out

if __name__ == "__main__":
    cfg = WorldConfig()
    mode = sys.argv[2] if len(sys.argv) > 2 else "tb"
    orig = steps.build_policy
    def patched(name, cfg, ck):
        p = orig(name, cfg, ck)
        p.features.hint = TBHint(cfg, mode)
        return p
    steps.build_policy = patched
    row = run(cfg, "commattn=results/hint/hint_checkpoint.pt", int(sys.argv[1]))
    print(mode, row["elratio"], row["per_episode"])
