"""The layering rule of docs/DECISIONS.md, checked on the source: each layer imports only the
layers below it (imports inside functions count), `swarm.net` never imports torch and
`swarm.learn` never imports zenoh."""

from __future__ import annotations

import ast
from pathlib import Path

from conftest import ROOT

LAYERS = ["world", "policies", "swarm.common", "swarm.net", "swarm.learn", "swarm.procs",
          "swarm.bench", "swarm.studies", "swarm.cli"]


def layer(module: str) -> int | None:
    for k in range(len(LAYERS) - 1, -1, -1):
        if module == LAYERS[k] or module.startswith(LAYERS[k] + "."):
            return k
    return None


def modules() -> dict[str, Path]:
    out = {}
    for top in ("world", "policies", "swarm"):
        for path in (ROOT / top).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


def imported(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
            names |= {f"{node.module}.{a.name}" for a in node.names}
    return names


def test_each_layer_imports_only_the_layers_below_it() -> None:
    bad = []
    for name, path in modules().items():
        if name == "swarm":
            continue
        mine = layer(name)
        assert mine is not None, f"{name} belongs to no layer"
        for imp in imported(path):
            theirs = layer(imp)
            if theirs is not None and theirs > mine:
                bad.append(f"{name} imports {imp}")
    assert not bad, bad


def test_net_never_imports_torch_and_learn_never_imports_zenoh() -> None:
    bad = []
    for name, path in modules().items():
        top = {i.split(".")[0] for i in imported(path)}
        if name.startswith("swarm.net") and "torch" in top:
            bad.append(f"{name} imports torch")
        if name.startswith(("swarm.learn", "swarm.common", "world", "policies")) and "zenoh" in top:
            bad.append(f"{name} imports zenoh")
    assert not bad, bad


def test_the_cli_and_a_frontier_robot_never_import_torch() -> None:
    """Every child process builds the whole parser: torch (~230 MB, ~2 s) must stay out of it."""
    import subprocess
    import sys

    code = ("import sys, swarm.cli, swarm.procs.robot, swarm.procs.world, swarm.procs.supervisor;"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.stdout.strip() == "False", out.stderr


def test_the_registry_knows_which_policies_are_chained_or_learned_without_importing_them(
        ) -> None:
    """CHAINED and LEARNED (what the world and the torch-free checks read) match the classes
    of this project's own policies (a plugin installed in the same environment is no concern
    of theirs: it is asked its class, and may not be learned)."""
    from policies import CHAINED, LEARNED, PLUGINS, REGISTRY, policy_class

    own = [n for n in REGISTRY if n not in PLUGINS]
    assert {n for n in own if policy_class(n).chained} == CHAINED
    assert {n for n in own if policy_class(n).learned} == LEARNED


def test_only_the_keys_module_formats_a_key() -> None:
    """Every key expression of a run comes from `swarm.net.keys.Keys` (its module docstring's
    promise): no other module builds one from a run's base (`swarm/<run>`) by hand."""
    import re

    by_hand = re.compile(r"\{[\w.]*base\}/|\.alive_\w+\.rsplit")
    bad = [str(p.relative_to(ROOT)) for n, p in modules().items()
           if n != "swarm.net.keys" and by_hand.search(p.read_text())]
    assert not bad, bad
