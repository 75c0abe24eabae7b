"""Policies of other packages (README, "Building on it: your policy, your analysis") that are
buggy: the batched evaluator and the swarm take the same answers as moves (one check,
`world.core.check_actions`), and a plugin that cannot be imported or built is one line naming
it, never a traceback, nor a command that breaks though it never asked for that plugin."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import CYCLIC_PLUGIN, ROOT, swarm

from world import core

PLUGIN = CYCLIC_PLUGIN + '''

class OutOfRange(Policy):
    def act(self, view, greedy=True):
        return np.full(view.receivers.shape, 42, dtype=np.int64)


class Floaty(Policy):
    def act(self, view, greedy=True):
        return np.full(view.receivers.shape, 1.5)


class Listy(Cyclic):
    def act(self, view, greedy=True):
        return super().act(view, greedy).tolist()


class Raiser(Policy):
    def act(self, view, greedy=True):
        raise RuntimeError("boom from my plugin")


class NoAct(Policy):
    pass


class BadInit(Cyclic):
    def __init__(self, cfg):
        raise ValueError("init failed")


class Chained(ChainPlan):
    name = "chained"
'''

ENTRIES = {"cyclic": "ua_plugin:Cyclic", "outofrange": "ua_plugin:OutOfRange",
           "floaty": "ua_plugin:Floaty", "listy": "ua_plugin:Listy",
           "raiser": "ua_plugin:Raiser", "noact": "ua_plugin:NoAct",
           "badinit": "ua_plugin:BadInit", "missing": "ua_plugin:Missing",
           "noimport": "no_such_module_here:X", "chained": "ua_plugin:Chained"}


def install(tmp_path: Path, *names: str) -> dict[str, str]:
    """PLUGIN on a path of its own with the entry points `names` of ENTRIES; the environment
    that makes it importable."""
    (tmp_path / "ua_plugin.py").write_text(PLUGIN)
    info = tmp_path / "ua_plugin-0.1.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: ua-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[commattn_swarm.policies]\n" + "".join(f"{n} = {ENTRIES[n]}\n" for n in names))
    return {"PYTHONPATH": str(tmp_path)}


def test_a_move_is_what_one_check_takes() -> None:
    """The world, the batched evaluator and a robot process ask `check_actions`: integers in
    0..8 of the team's shape; a list of them is as good as its array."""
    ok = core.check_actions([[0, 8, 3]], (1, 3))
    assert isinstance(ok, np.ndarray) and ok.tolist() == [[0, 8, 3]]
    for bad, why in (([[0, 42, 0]], "integers in 0..8"), ([[0, 1.5, 0]], "integers in 0..8"),
                     ([[0, -1, 0]], "integers in 0..8"), ([[True, False, True]], "0..8"),
                     ([[0, np.nan, 0]], "integers in 0..8"), ([0, 1, 2], "shape (1, 3)"),
                     ([[0, 1], [2]], "shape (1, 3)")):
        with pytest.raises(ValueError, match=re.escape(why)):
            core.check_actions(bad, (1, 3))


@pytest.mark.procs
@pytest.mark.parametrize("name", ["outofrange", "floaty"])
def test_a_plugin_answering_no_move_stays_in_place_in_the_swarm_as_eval_refuses_it(
        tmp_path: Path, name: str) -> None:
    """Before, 42 went to the world, which dropped it as a bad payload and waited out its
    watchdog every tick (0.1 ticks/s, exit 0, no word), and 1.5 moved north (int(1.5)) where
    `swarm eval` refused it."""
    env, run = install(tmp_path, name), tmp_path / "run.json"
    r = swarm("eval", "--policy", name, "--robots", "3", "--episodes", "1", env=env)
    assert r.returncode == 2 and "actions must be integers in 0..8" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    r = swarm("run", "--headless", "--policy", name, "--robots", "3", "--episodes", "1",
              "--horizon", "4", "--watchdog", "600", "--json", str(run), env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    for i in range(3):
        assert f"robot {i} could not decide on 4 ticks" in r.stderr, r.stderr
    res = json.loads(run.read_text())
    assert res["timeouts"] == 0 and not np.array(res["actions"]).any()
    assert all(s["errors"] == 4 for s in res["robot_status"].values())


@pytest.mark.procs
def test_a_plugin_answering_a_list_acts_the_same_in_eval_and_in_the_swarm(
        tmp_path: Path) -> None:
    """Before, eval took the list and every robot failed on it (an error each tick). Both name
    it as the user did (its class calls itself `cyclic`, inherited)."""
    env, ev, run = install(tmp_path, "listy"), tmp_path / "eval.json", tmp_path / "run.json"
    common = ["--policy", "listy", "--robots", "3", "--episodes", "1", "--horizon", "6"]
    r = swarm("eval", *common, "--json", str(ev), env=env)
    assert r.returncode == 0, r.stderr
    r = swarm("run", "--headless", *common, "--json", str(run), env=env)
    assert r.returncode == 0 and "could not decide" not in r.stderr, r.stderr
    res = json.loads(run.read_text())
    assert res["elratio_mean"] == pytest.approx(json.loads(ev.read_text())["elratio_mean"])
    assert res["policy"] == json.loads(ev.read_text())["policy"] == "listy"
    assert np.array_equal(np.array(res["actions"])[0, 0], [0, 1, 2])


@pytest.mark.parametrize(("name", "why"), [
    ("raiser", "policy raiser: act raised RuntimeError: boom from my plugin"),
    ("noact", "policy plugin 'noact' (ua_plugin:NoAct) does not implement act"),
    ("badinit", "policy plugin 'badinit' (ua_plugin:BadInit) could not be built: "
                "ValueError: init failed"),
    ("missing", "policy plugin 'missing' (ua_plugin:Missing): ua_plugin has no Missing")])
def test_a_plugin_that_cannot_act_or_be_built_is_one_line_naming_it(
        tmp_path: Path, name: str, why: str) -> None:
    """Before: a 20-line traceback (abstract class, raising constructor), a line without the
    policy's name (act raised; then one with its class's name, not the one the user typed) or
    one calling a missing class no Policy subclass."""
    env = install(tmp_path, name)
    commands = [["eval", "--policy", name, "--robots", "3", "--episodes", "1"]]
    if name != "raiser":  # (refused before any process is spawned)
        commands.append(["run", "--headless", "--policy", name, "--robots", "3",
                         "--episodes", "1"])
    for args in commands:
        r = swarm(*args, env=env)
        said = [line for line in r.stderr.splitlines() if line.startswith("swarm:")]
        assert r.returncode == 2 and said == [f"swarm: error: {why}"], r.stderr
        assert "Traceback" not in r.stderr


def test_a_plugin_that_does_not_import_breaks_no_command_that_does_not_ask_for_it(
        tmp_path: Path) -> None:
    """Before, `swarm repro` imported every registered policy at start (a traceback for every
    item) and `swarm bench policy` (every policy by default) stopped at it, and at a plugin
    whose constructor raised."""
    env = install(tmp_path, "noimport", "badinit", "cyclic")
    r = swarm("repro", "fig8", "--out", str(tmp_path / "repro"), env=env)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    r = swarm("bench", "policy", "--decisions", "1", "--warmup", "0", "--robots", "3",
              "--horizon", "4", "--json", str(tmp_path / "bench.json"), env=env)
    assert r.returncode == 0, r.stderr
    assert "swarm: warning: policy plugin 'noimport' (no_such_module_here:X) does not " \
           "import: ModuleNotFoundError" in r.stderr and "; skipped" in r.stderr, r.stderr
    assert "swarm: warning: policy plugin 'badinit' (ua_plugin:BadInit) could not be built: " \
           "ValueError: init failed; skipped" in r.stderr, r.stderr
    timed = [row["policy"] for row in json.loads((tmp_path / "bench.json").read_text())["rows"]]
    assert "cyclic" in timed and "nearest-frontier" in timed
    assert "noimport" not in timed and "badinit" not in timed
    # asked for by name, it stops the command before anything is timed
    r = swarm("bench", "policy", "--policies", "badinit,cyclic", "--decisions", "1", env=env)
    assert r.returncode == 2 and "could not be built" in r.stderr, r.stderr


@pytest.mark.parametrize(("name", "why"), [
    ("outofrange", "policy outofrange: actions must be integers in 0..8, got int64 [42, 42, 42]"),
    ("raiser", "policy raiser: act raised RuntimeError: boom from my plugin")])
def test_bench_policy_names_a_plugin_that_answers_no_move_or_raises(
        tmp_path: Path, name: str, why: str) -> None:
    """Before: a traceback from the world's step (42) or a line without the policy's name
    (raised), and with every policy (the default) the whole bench stopped at the plugin. Now
    asked for, it is one line naming it, as in `swarm eval`; by default it is skipped, as one
    that does not import."""
    env = install(tmp_path, name)
    small = ["--decisions", "1", "--warmup", "0", "--robots", "3", "--horizon", "4"]
    for one_robot in ([], ["--one-robot"]):
        r = swarm("bench", "policy", "--policies", name, *small, *one_robot, env=env)
        said = [line for line in r.stderr.splitlines() if line.startswith("swarm:")]
        assert r.returncode == 2 and said == [f"swarm: error: {why}"], r.stderr
        assert "Traceback" not in r.stderr
    r = swarm("bench", "policy", *small, "--json", str(tmp_path / "bench.json"), env=env)
    assert r.returncode == 0 and f"swarm: warning: {why}; skipped" in r.stderr, r.stderr
    timed = [row["policy"] for row in json.loads((tmp_path / "bench.json").read_text())["rows"]]
    assert name not in timed and "nearest-frontier" in timed


def test_the_project_s_own_registry_checks_pass_with_a_chained_plugin_installed(
        tmp_path: Path) -> None:
    """tests/test_layout.py compared CHAINED with every registered class, a plugin's too."""
    env = install(tmp_path, "chained")
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider",
                        "tests/test_layout.py", "-k", "registry"], cwd=ROOT, text=True,
                       capture_output=True, timeout=300, env={**os.environ, **env})
    assert r.returncode == 0, r.stdout[-2000:]


def test_a_chained_policy_s_decision_is_public() -> None:
    """A chained plugin's `decide` returns `policies.base.Decision` (there were two private
    copies, and the README named none)."""
    from policies import chain_plan
    from policies.base import Decision

    assert chain_plan.Decision is Decision and Decision._fields == ("actions", "state")


def test_a_policy_a_script_adds_to_the_registry_is_usable_by_its_name() -> None:
    """Review 85: once the installed packages were scanned lazily, a name a script put into
    `policies.REGISTRY` was listed but refused ("unknown policy"); it is a policy like the
    built-ins (no plugin checks), and the lazily served names are still in `dir(policies)`."""
    import policies
    from swarm.common.policy_spec import resolve_policies
    from world.config import WorldConfig

    policies.REGISTRY["script-nearest"] = "policies.nearest_frontier:NearestFrontier"
    try:
        cfg = WorldConfig(n_robots=2)
        assert type(policies.make_policy("script-nearest", cfg)).__name__ == "NearestFrontier"
        assert resolve_policies("script-nearest") == ["script-nearest"]
        assert not policies.is_plugin("script-nearest")
        assert {"REGISTRY", "PLUGINS", "SKIPPED"} <= set(dir(policies))
    finally:
        del policies.REGISTRY["script-nearest"]
