"""Policy registry: the CLI name maps to `module:Class`; the module's file name is its key.

Imports are lazy so that running a frontier policy never imports torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from policies.base import Policy
    from world.config import WorldConfig

REGISTRY: dict[str, str] = {
    "random": "policies.random_policy:RandomPolicy",
    "nearest-frontier": "policies.nearest_frontier:NearestFrontier",
    "coordinated-frontier": "policies.coordinated_frontier:CoordinatedFrontier",
    "cost-utility": "policies.cost_utility:CostUtility",
    "commattn": "policies.commattn:CommAttnPolicy",
    "commnet": "policies.commnet:CommNetPolicy",
    "vain": "policies.vain:VAINPolicy",
    "bicnet": "policies.bicnet:BicNetPolicy",
    "oracle": "policies.oracle:OraclePolicy",
    "central": "policies.central:CentralPolicy",
    "team-beam": "policies.team_beam:TeamBeam",
    "chain-plan": "policies.chain_plan:ChainPlan",
}

BASELINES = ("random", "nearest-frontier", "coordinated-frontier", "cost-utility")
# Policies whose robots send hidden-state messages along the id chain (SPEC 3.5), known without
# importing them (the world process never imports torch); tests check it against the classes.
CHAINED = frozenset({"commattn", "chain-plan"})
# Learned policies (a torch network to train, a numpy twin in policies.infer.nets to act with).
LEARNED = frozenset({"commattn", "commnet", "vain", "bicnet"})
# Policies `swarm train --imitate` can learn from: they act on a View alone (the oracle reads the
# episode's future from the world, so it cannot label states a learner visits).
TEACHERS = ("team-beam", "central", "coordinated-frontier", "nearest-frontier", "cost-utility")


def policy_class(name: str) -> type[Policy]:
    """The class registered under `name`; an unknown name is a one-line ValueError."""
    try:
        target = REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown policy {name!r}; choose from {', '.join(REGISTRY)}") from None
    module, cls = target.split(":")
    return getattr(importlib.import_module(module), cls)


def check_learned(name: str, what: str) -> None:
    """A one-line ConfigError unless `name` is a registered learned policy (`what` needs one);
    from the names alone, so a refusal costs no torch import."""
    from world.config import ConfigError

    if name not in REGISTRY:
        raise ConfigError(f"unknown policy {name!r}; choose from {', '.join(REGISTRY)}")
    if name not in LEARNED:
        raise ConfigError(f"{what} needs a learned policy, not {name!r}")


def learned_names() -> tuple[str, ...]:
    """Registry names of the learned (torch) policies, in registry order (imports them)."""
    return tuple(name for name in REGISTRY if policy_class(name).learned)


def make_policy(name: str, cfg: WorldConfig, **kwargs: object) -> Policy:
    return policy_class(name)(cfg, **kwargs)  # type: ignore[call-arg]
