"""The hint network given `team-beam`'s chosen move as its hint instead of coordinated
frontier's moves, at test time only (no training): `TBHint` replaces the Featurizer's planner.
Mode `tb`: team-beam's move alone; `and`: team-beam's move where coordinated frontier's set
contains it, else coordinated frontier's set. Run through `paired.py` (see ../README.md)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from policies.coordinated_frontier import CoordinatedFrontier
from policies.team_beam import TeamBeam
from world.config import WorldConfig
from world.decentral import View


class TBHint:
    """`first_moves` as the Featurizer calls it, from `team-beam`'s plan on the same belief."""

    def __init__(self, cfg: WorldConfig, mode: str) -> None:
        self.tb, self.cf, self.mode = TeamBeam(cfg), CoordinatedFrontier(cfg), mode

    def first_moves(self, view: View, snap: object) -> np.ndarray:
        g, i, r = snap.g, snap.i, snap.size  # type: ignore[attr-defined]
        team = view.hears[g, i] & view.msgs.present[g]
        pos = np.where(team[..., None], view.msgs.pos[g], snap.cells[:, None, :])  # type: ignore[attr-defined]
        sub = SimpleNamespace(msgs=SimpleNamespace(present=team, pos=pos), n=view.n,
                              tick=view.tick, seed=view.seed,
                              episodes=np.asarray(view.episodes)[g])
        self.tb.known = snap.known.reshape(r, -1)  # type: ignore[attr-defined]
        self.tb.explored = snap.explored.reshape(r, -1)  # type: ignore[attr-defined]
        a = self.tb.plan(sub, np.arange(r))[np.arange(r), i]  # type: ignore[arg-type]
        out = np.zeros((r, 9), dtype=bool)
        out[np.arange(r), a] = True
        if self.mode == "and":
            cf = self.cf.first_moves(view, snap)  # type: ignore[arg-type]
            out = np.where((out & cf).any(1, keepdims=True), out, cf)
        return out
