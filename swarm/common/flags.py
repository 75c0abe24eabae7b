"""Config dataclasses as command-line flags: one flag per field, its help the field's docstring.

A flag left unset is None and keeps the value from the TOML table or the default, so the
precedence is always defaults < `--config FILE` table < flags (see `swarm.cli.common.merged`).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import itertools
from typing import Any

from world.config import MAX_SIDE, ConfigError, replace

HELP = True
"""Whether `add_flags` gives each flag its field's docstring as help: a process the supervisor
spawned never prints a help, so `swarm.cli.main` turns it off there (reading the docstrings
parses the dataclasses' source: ~30 ms of each child's start)."""


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of dataclass `cls` (one line, `%` escaped for argparse)."""
    tree = ast.parse(inspect.getsource(cls))
    body = tree.body[0].body  # type: ignore[attr-defined]
    out = {}
    for node, nxt in itertools.pairwise(body):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)):
            out[node.target.id] = " ".join(str(nxt.value.value).split()).replace("%", "%%")
    return out


def _bool(text: str) -> bool:
    if text.lower() not in ("1", "0", "true", "false", "yes", "no"):
        raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
    return text.lower() in ("1", "true", "yes")


def robot_id(text: str) -> int:
    """An argparse type: a robot id is an integer >= 0 (its upper end is the run's team, which
    only the world knows), refused before any connection is tried."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a robot id (an integer >= 0), got {text!r}"
                                         ) from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"a robot id is >= 0, got {value}")
    if value >= MAX_SIDE * MAX_SIDE:  # (no team is larger than the largest grid's cells)
        raise argparse.ArgumentTypeError(f"a robot id is below {MAX_SIDE * MAX_SIDE} (a team has "
                                         f"at most one robot a cell of a {MAX_SIDE} x {MAX_SIDE} "
                                         f"grid), got {value}")
    return value


def add_flags(parser: argparse.ArgumentParser | Any, cls: type, skip: tuple[str, ...] = (),
              dest_prefix: str = "") -> None:
    """One `--field-name` flag per field of `cls` (ints, floats, strings, bools); fields in
    `skip` and flags the parser already has (a shared --seed, say) are left out."""
    docs = field_docs(cls) if HELP else {}
    for f in dataclasses.fields(cls):
        flag = "--" + f.name.replace("_", "-")
        if f.name in skip or flag in parser._option_string_actions:
            continue
        ftype = str(f.type).replace(" | None", "")
        dest = dest_prefix + f.name
        doc = docs.get(f.name, "")
        if f.default not in (dataclasses.MISSING, None, "") and "default" not in doc.lower():
            shown = str(f.default).lower() if isinstance(f.default, bool) else f.default
            doc += f" (default {shown})"  # (argparse's own default is None: "not given")
        if ftype == "bool":
            parser.add_argument(flag, dest=dest, type=_bool, default=None, metavar="BOOL",
                                help=doc)
        else:
            kind = {"int": int, "float": float}.get(ftype, str)
            parser.add_argument(flag, dest=dest, type=kind, default=None, help=doc)


def given(cls: type, args: argparse.Namespace, dest_prefix: str = "") -> dict[str, Any]:
    """The fields of `cls` whose flags were given, as a dict."""
    out = {}
    for f in dataclasses.fields(cls):
        value = getattr(args, dest_prefix + f.name, None)
        if value is not None:
            out[f.name] = value
    return out


def from_flags(cls: type, args: argparse.Namespace, base: Any = None,
               dest_prefix: str = "") -> Any:
    """`base` (default: the defaults of `cls`) with every flag that was given applied."""
    return replace(base if base is not None else cls(), **given(cls, args, dest_prefix))


def check_wait(value: Any, flag: str = "--wait") -> None:
    """A wait in seconds (`swarm fault|robot|record|rollout-worker --wait`): a number in
    [0.1, 3600]; NaN or inf would wait for ever. One-line ConfigError otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.1 <= value <= 3600:
        raise ConfigError(f"{flag} must lie in [0.1, 3600] seconds, got {value}")  # (NaN too)
