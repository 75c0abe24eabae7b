"""The floor: every robot picks one of the 9 actions uniformly (counter-based noise)."""

from __future__ import annotations

import numpy as np

from policies.base import Policy, receiver_index
from world.core import N_ACTIONS
from world.decentral import View
from world.noise import uniform


class RandomPolicy(Policy):
    name = "random"

    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        g, i = receiver_index(view)
        out = np.zeros(view.receivers.shape, dtype=np.int64)
        u = uniform(view.seed, view.episodes[g], view.tick, i, 1, stream=2)[:, 0]
        out[g, i] = np.minimum((u * N_ACTIONS).astype(np.int64), N_ACTIONS - 1)
        return out
