"""`team-beam`: `central`'s planner run by every robot alone, on what that robot knows.

A decentralized hand-written planner (ours, not the paper's). Each robot keeps the belief the
frontier baselines keep (`policies.belief`: the blocks it saw or heard of, the cells the team
visited as far as it heard), takes the robots it hears this tick as its team, plans all of them
with `central`'s prioritized beam search (`CentralPolicy.plan`: each robot of the team in a
rotating order, a 6-step beam against the paths fixed before it, two passes) and takes its own
first move. Robots it does not hear do not exist for it: their positions are never read.

Every (episode, receiver) pair is one group of `CentralPolicy.plan`, so the batch plans all
receivers at once and a robot process plans its one. The beam's noise is keyed by the episode,
tick and planned robot, not by the receiver: robots that know the same make the same joint plan
(a convention, not a message), so with a radio that reaches everyone `team-beam` is `central`
(tested), and with a shorter one each robot's plan is `central`'s over what it heard. It costs
one `central` team decision per robot: ~10-13 ms for one robot's decision on 20 x 20 with 10
robots (`swarm bench policy --policies team-beam --one-robot`), ~1.8 ms each batched
(docs/DECISIONS.md "`team-beam`" has the measurements).

`first_moves` hands its move to a learned network as its planner hint (model field
`hint_planner`, policies.infer.tokens).
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import ClassVar

import numpy as np

from policies.belief import Belief, Snapshot
from policies.central import CentralConfig, CentralPolicy
from world.config import WorldConfig
from world.decentral import View


class TeamBeam(CentralPolicy):
    """Every robot plans its heard team with `central`'s beam and takes its own first move."""

    name = "team-beam"
    decentralized: ClassVar[bool] = True

    def __init__(self, cfg: WorldConfig, search: CentralConfig | None = None) -> None:
        super().__init__(cfg, search)
        self.belief = Belief(cfg)

    def reset(self, groups: int) -> None:
        self.belief.reset(groups)

    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        snap = self.belief.snapshot(view)
        out = np.zeros(view.receivers.shape, dtype=np.int64)
        if snap.size:
            out[snap.g, snap.i] = self.own_moves(view, snap)
        return out

    def own_moves(self, view: View, snap: Snapshot) -> np.ndarray:
        """The first move [R] of each receiver of `snap` in the joint plan of its heard team."""
        g, i, r = snap.g, snap.i, snap.size
        team = view.hears[g, i] & view.msgs.present[g]  # [R, N]
        pos = np.where(team[..., None], view.msgs.pos[g], snap.cells[:, None, :])
        sub = SimpleNamespace(msgs=SimpleNamespace(present=team, pos=pos), n=view.n,
                              tick=view.tick, seed=view.seed,
                              episodes=np.asarray(view.episodes)[g])
        self.known = snap.known.reshape(r, -1)  # the beliefs `plan` reads, one row per receiver
        self.explored = snap.explored.reshape(r, -1)
        return self.plan(sub, np.arange(r))[np.arange(r), i]  # type: ignore[arg-type]

    def first_moves(self, view: View, snap: Snapshot) -> np.ndarray:
        """`own_moves` as a one-hot [R, 9] bool: a network's planner hint (policies.infer.tokens,
        `hint_planner` "team-beam"), in the form coordinated frontier's `first_moves` takes."""
        out = np.zeros((snap.size, 9), dtype=bool)
        if snap.size:
            out[np.arange(snap.size), self.own_moves(view, snap)] = True
        return out
