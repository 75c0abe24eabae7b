"""The one policy interface answered by every policy, learned and pre-designed."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar, NamedTuple

import numpy as np

from world.config import WorldConfig
from world.decentral import View


class Policy(ABC):
    """A decentralized policy: receiver i decides from the messages it heard (View.hears[g, i]).

    Shapes: G groups (episodes), N robot slots. `act` returns actions [G, N] int64 in 0..8 for
    every `view.receivers` entry and 0 elsewhere. A receiver's decision may depend only on its
    own message, the messages it heard, its own memory from earlier ticks of the episode and
    the counter-based noise keyed by (seed, episode, tick, robot); so the batched evaluator (all
    receivers at once) and a robot process (one receiver) decide the same.
    """

    name: ClassVar[str] = ""
    learned: ClassVar[bool] = False
    chained: ClassVar[bool] = False  # needs the predecessor's hidden-state message (SPEC 3.5)
    decentralized: ClassVar[bool] = True
    """False for reference planners (oracle, central) that read more than a robot could hear."""

    def __init__(self, cfg: WorldConfig) -> None:
        self.cfg = cfg

    def reset(self, groups: int) -> None:  # noqa: B027 (a no-op unless the policy remembers)
        """Start new episodes for `groups` groups: forget every receiver's memory."""

    def state_ok(self, state: np.ndarray, tick: int) -> bool:
        """Whether a predecessor's hidden-state message of tick `tick` (chained policies; its
        size is checked before) is one this policy can read; one that is not counts as lost."""
        return True

    @abstractmethod
    def act(self, view: View, greedy: bool = True) -> np.ndarray:
        """Actions [G, N] for the view's receivers; `greedy=False` samples where that differs."""


class Decision(NamedTuple):
    """A chained policy's batched decision (its `decide(view)`): every receiver's action and
    the hidden-state message it sends on to its successor (SPEC 3.5), zeros off the
    receivers. A robot process gets the same from `act_with_chain` for its one receiver."""

    actions: np.ndarray  # [G, N] int64
    state: np.ndarray  # [G, N, state_size] float32


def receiver_index(view: View) -> tuple[np.ndarray, np.ndarray]:
    """(group, robot) index arrays of the receivers, in group-major, id order."""
    return np.nonzero(view.receivers)
