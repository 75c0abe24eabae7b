"""Policy names as the command line gives them, resolved against the registry and built.

Every subcommand that takes `--policy`/`--policies` goes through here, so a learned policy
registered in `policies.REGISTRY` becomes usable everywhere by its name alone.
"""

from __future__ import annotations

import re
from pathlib import Path

from policies import (
    BASELINES,
    LEARNED,
    PluginError,
    is_registered,
    make_policy,
    policy_class,
    registered,
)
from policies.base import Policy
from swarm.common.shipped import ROOT, SEARCHED, SHIPPED
from world.config import ConfigError, WorldConfig


def _entries(spec: str | list[str] | tuple[str, ...]) -> list[str]:
    """The names of a comma-separated list (or a config file's list), stripped: a name that is
    no text (`policies = [5]`: a traceback) or an empty entry among others (`,random`, silently
    dropped) is one line."""
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    odd = [s for s in items if not isinstance(s, str)]
    if odd:
        raise ConfigError(f"a policy is named by its name (text), got {odd[0]!r:.40}")
    if len(items) > 1 and any(not s.strip() for s in items):
        raise ConfigError(f"an empty policy name in {','.join(items)!r:.80}")
    return [s.strip() for s in items if s.strip()]


def resolve_policies(spec: str | list[str] | tuple[str, ...]) -> list[str]:
    """`all`, one name or a comma-separated list -> registry names (order kept, no repeats: a
    name `all` also brings is taken once; one written twice is a typo, refused)."""
    names: list[str] = []
    written = _entries(spec)
    if twice := next((n for n in written if written.count(n) > 1), None):
        raise ConfigError(f"policy {twice!r} is named {written.count(twice)} times: each policy "
                          "runs once")
    for item in written:
        expanded = list(BASELINES) if item == "all" else [item]
        for name in expanded:
            if not is_registered(name):
                known = ", ".join(registered())
                raise ConfigError(f"unknown policy {name!r}; choose from all, {known}")
            if name not in names:
                names.append(name)
    if not names:
        raise ConfigError("no policy given")
    return names


def labelled_policies(spec: str | list[str] | tuple[str, ...]) -> list[tuple[str, str]]:
    """`swarm eval --policy`: `resolve_policies`' entries, any of them `LABEL=NAME`, as (label,
    registry name) in the order written; a plain name is its own label. A label runs one policy
    a second time under a name of its own, e.g. your checkpoint beside the shipped one:
    `commattn,mine=commattn --checkpoint mine=FILE` (paired over the same episodes)."""
    items = _entries(spec)
    plain = [s for s in items if "=" not in s]
    if plain:
        resolve_policies(plain)  # (unknown or repeated names: its one line)
    out: dict[str, str] = {}
    for item in items:
        label, sep, name = (s.strip() for s in item.partition("="))
        if not sep:
            out.update({n: n for n in (BASELINES if item == "all" else [item]) if n not in out})
            continue
        if not re.fullmatch(r"[A-Za-z][\w-]*", label) or is_registered(label) or label == "all":
            raise ConfigError(f"--policy {item}: LABEL=NAME wants a label of letters, digits, "
                              "'-' and '_' that is no policy's name")
        if label in out or name == "all":
            raise ConfigError(f"--policy {item}: " + ("a label names one policy, not all"
                              if name == "all" else f"{label!r} is named twice"))
        out[label] = resolve_policies([name])[0]
    if not out:
        raise ConfigError("no policy given")
    return list(out.items())


def load_class(name: str) -> type[Policy]:
    """The registered class; a module that cannot be imported is a one-line ConfigError."""
    try:
        return policy_class(name)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    except ImportError as exc:
        raise ConfigError(f"policy {name!r} is registered but cannot be imported: {exc}") from None


def shown(path: str | None) -> str | None:
    """A path as a result file records it: relative to the repository root when inside it
    (so a committed result names no machine's directories), else as given."""
    if path is None:
        return None
    p = Path(path).resolve()
    return str(p.relative_to(ROOT)) if p.is_relative_to(ROOT) else path


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes: what a resumed study compares, so that a checkpoint
    retrained or replaced in place is not taken for the one its rows were made with."""
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def effective_checkpoint(name: str, checkpoint: str | None) -> str | None:
    """The checkpoint a policy runs with: the one given, else for a learned policy the one
    shipped as checkpoints/NAME.pt (a learned policy never runs on untrained weights by
    accident; `swarm train` makes fresh ones)."""
    if checkpoint is not None or name not in LEARNED:
        return checkpoint
    shipped = SHIPPED / f"{name}.pt"
    if not shipped.is_file():
        raise ConfigError(f"policy {name!r} needs --checkpoint FILE (no {name}.pt in {SEARCHED})")
    return str(shipped)


def build_policy(name: str, cfg: WorldConfig, checkpoint: str | None = None) -> Policy:
    """Instantiate policy `name` for `cfg`; learned policies load `checkpoint` (by default the
    shipped one, see `effective_checkpoint`).

    A learned policy class loads a checkpoint through its constructor: `cls(cfg, checkpoint=path)`.
    """
    cls = load_class(name)
    checkpoint = effective_checkpoint(name, checkpoint)
    if checkpoint is None:
        try:
            return make_policy(name, cfg)
        except PluginError as exc:  # (a plugin whose constructor raised)
            raise ConfigError(str(exc)) from None
    if not cls.learned:
        raise ConfigError(f"a checkpoint (--checkpoint) applies to learned policies only, not "
                          f"{name!r}")
    from policies.checkpoint import CheckpointError, check_exists

    try:
        check_exists(Path(checkpoint))
        return cls(cfg, checkpoint=checkpoint)  # type: ignore[call-arg]
    except CheckpointError as exc:
        raise ConfigError(str(exc)) from None


def build_inference(name: str, cfg: WorldConfig, checkpoint: str | None = None) -> Policy:
    """`build_policy` for a robot process: a learned policy acts in numpy, without torch
    (policies.infer), from the same checkpoint; other policies are built as usual."""
    if name not in LEARNED:
        return build_policy(name, cfg, checkpoint)
    from policies.checkpoint import CheckpointError
    from policies.infer.policy import inference_class

    checkpoint = effective_checkpoint(name, checkpoint)
    try:
        return inference_class(name)(cfg, checkpoint=checkpoint)
    except CheckpointError as exc:
        raise ConfigError(str(exc)) from None
