"""Policy registry: the CLI name (its key) maps to `module:Class` (`random` ->
`policies.random_policy:RandomPolicy`).

Imports are lazy so that running a frontier policy never imports torch. Policies of other
packages join the registry through the `commattn_swarm.policies` entry-point group (README,
"Building on it: your policy, your analysis"): hand-written ones only (a learned policy needs a
numpy twin here).
"""

from __future__ import annotations

import importlib
import inspect
import sys
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from policies.base import Policy
    from world.config import WorldConfig

_REGISTRY: dict[str, str] = {
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

PLUGIN_GROUP = "commattn_swarm.policies"


BUILTIN = frozenset(_REGISTRY)
"""The policies of this package (known without looking at the installed packages)."""
_SKIPPED: list[str] = []
_PLUGINS: dict[str, str] | None = None  # (scanned on first use: `_plugins`)


def _plugins() -> dict[str, str]:
    """`name = "module:Class"` entry points of installed packages, scanned once, on first use
    (importlib.metadata and the scan cost each process ~60 ms, and a robot of a built-in policy
    never needs them); one that shadows a built-in name or is not `module:Class` is skipped,
    noted in SKIPPED. The plugins join REGISTRY."""
    global _PLUGINS
    if _PLUGINS is not None:
        return _PLUGINS
    from importlib import metadata

    found: dict[str, str] = {}
    for ep in metadata.entry_points(group=PLUGIN_GROUP):
        module, sep, cls = ep.value.partition(":")
        why = ("shadows a built-in policy" if ep.name in BUILTIN else
               "is not 'module:Class'" if not (module and sep and cls) else "")
        if why:
            _SKIPPED.append(f"policy plugin {ep.name!r} = {ep.value!r} {why}; skipped")
            continue
        found[ep.name] = ep.value
    _REGISTRY.update(found)
    _PLUGINS = found
    return found


def __getattr__(attr: str) -> Any:
    """REGISTRY (every policy: the built-ins, then the plugins), PLUGINS (policies registered
    by other packages through the `commattn_swarm.policies` entry points) and SKIPPED (one line
    per entry point skipped: `swarm` prints them once a command, its children do not repeat
    them; a library user reads them here): the installed packages are scanned on first use."""
    if attr in ("REGISTRY", "PLUGINS", "SKIPPED"):
        plugins = _plugins()
        return {"REGISTRY": _REGISTRY, "PLUGINS": plugins, "SKIPPED": _SKIPPED}[attr]
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), "REGISTRY", "PLUGINS", "SKIPPED"])


def is_plugin(name: str) -> bool:
    """Whether `name` is a policy of another package (a built-in name scans nothing)."""
    return name not in BUILTIN and name in _plugins()


def is_registered(name: str) -> bool:
    """Whether `name` is a registered policy: built-in, added to REGISTRY by a script, or an
    installed plugin (only a name not yet in the registry scans the installed packages)."""
    return name in _REGISTRY or name in _plugins()


def registered() -> tuple[str, ...]:
    """Every registered policy name: the built-ins, then the plugins."""
    _plugins()
    return tuple(_REGISTRY)


BASELINES = ("random", "nearest-frontier", "coordinated-frontier", "cost-utility")
# Policies whose robots send hidden-state messages along the id chain (SPEC 3.5), known without
# importing them (the world process never imports torch); tests check it against the classes.
CHAINED = frozenset({"commattn", "chain-plan"})
# Learned policies (a torch network to train, a numpy twin in policies.infer.nets to act with).
LEARNED = frozenset({"commattn", "commnet", "vain", "bicnet"})
# Policies `swarm train --imitate` can learn from: they act on a View alone (the oracle reads the
# episode's future from the world, so it cannot label states a learner visits).
TEACHERS = ("team-beam", "central", "coordinated-frontier", "nearest-frontier", "cost-utility")


class PluginError(ValueError):
    """A policy of another package that cannot be used: it does not import, is no `Policy`
    subclass, is abstract, or its constructor raised; one line naming the plugin."""


def policy_class(name: str) -> type[Policy]:
    """The class registered under `name`; an unknown name is a one-line ValueError, a plugin
    that cannot be used a one-line PluginError."""
    if not is_registered(name):
        raise ValueError(f"unknown policy {name!r}; choose from {', '.join(registered())}")
    target, plugin = _REGISTRY[name], is_plugin(name)
    module, cls = target.split(":")
    try:
        found = getattr(importlib.import_module(module), cls, None)
    except Exception as exc:  # (another package's module: a SyntaxError there is one line too)
        if not plugin:
            raise
        raise PluginError(f"policy plugin {name!r} ({target}) does not import: "
                          f"{type(exc).__name__}: {exc}") from None
    if found is None:
        kind = PluginError if plugin else ValueError
        raise kind(f"policy {'plugin ' if plugin else ''}{name!r} ({target}): "
                   f"{module} has no {cls}")
    if plugin:  # another package's class: checked before anyone builds it
        from policies.base import Policy

        if not (isinstance(found, type) and issubclass(found, Policy)):
            raise PluginError(f"policy plugin {name!r} ({target}) is not a policies.base.Policy "
                              "subclass")
        if inspect.isabstract(found):
            missing = ", ".join(sorted(found.__abstractmethods__))
            raise PluginError(f"policy plugin {name!r} ({target}) does not implement {missing}")
        if found.learned:
            raise PluginError(f"policy plugin {name!r} is learned: plugins are hand-written "
                              "policies (a learned one needs a numpy twin in policies.infer)")
    return found


def loadable(names: Iterable[str] | None = None) -> tuple[str, ...]:
    """`names` (default: every registered one) but the plugins that cannot be used, each
    skipped with a one-line warning: for the commands that take every policy by default."""
    kept = []
    for name in registered() if names is None else names:
        if is_plugin(name):
            try:
                policy_class(name)
            except PluginError as exc:
                print(f"swarm: warning: {exc}; skipped", file=sys.stderr)
                continue
        kept.append(name)
    return tuple(kept)


def is_chained(name: str) -> bool:
    """Whether robots of policy `name` pass hidden-state messages down the id chain (SPEC
    3.5): built-ins from CHAINED (no import), a plugin from its class."""
    return name in CHAINED or (is_plugin(name) and policy_class(name).chained)


def check_learned(name: str, what: str) -> None:
    """A one-line ConfigError unless `name` is a registered learned policy (`what` needs one);
    from the names alone, so a refusal costs no torch import."""
    from world.config import ConfigError

    if not is_registered(name):
        raise ConfigError(f"unknown policy {name!r}; choose from {', '.join(registered())}")
    if name not in LEARNED:
        raise ConfigError(f"{what} needs a learned policy, not {name!r}")


def learned_names() -> tuple[str, ...]:
    """Registry names of the learned (torch) policies, in registry order, from the names alone
    (a plugin is never learned, so none is imported: one that does not import breaks nothing)."""
    return tuple(name for name in _REGISTRY if name in LEARNED)


def make_policy(name: str, cfg: WorldConfig, **kwargs: object) -> Policy:
    """Policy `name` for `cfg` as its class builds it: a learned one without `checkpoint=`
    has fresh random weights (for training and tests). The shipped networks, as every command
    runs them: `swarm.common.policy_spec.build_policy(name, cfg)`. A plugin whose constructor
    raises is a one-line PluginError naming it; a plugin's policy answers to its registered
    name (`.name`: the one the user typed, whatever its class calls itself)."""
    cls = policy_class(name)
    if "checkpoint" in kwargs and not cls.learned:  # (a bare TypeError from its __init__)
        raise ValueError(f"a checkpoint applies to learned policies only, not {name!r}")
    if not is_plugin(name):
        return cls(cfg, **kwargs)  # type: ignore[call-arg]
    try:
        policy = cls(cfg, **kwargs)  # type: ignore[call-arg]
    except Exception as exc:  # (another package's bug: whatever it raises)
        raise PluginError(f"policy plugin {name!r} ({_REGISTRY[name]}) could not be built: "
                          f"{type(exc).__name__}: {exc}") from None
    policy.name = name  # type: ignore[misc]
    return policy
