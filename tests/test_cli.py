"""The `swarm` CLI as a user runs it: real subprocesses, tiny budgets; plus its pure renderers."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
import time
from io import StringIO
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, swarm, swarm_here
from rich.console import Console

from swarm.cli.batch import EvalConfig
from swarm.cli.common import file_tables, merged, world_config
from swarm.cli.console import (
    env_bench_table,
    eval_table,
    policy_bench_table,
    sweep_table,
    table1_table,
)
from world.config import ConfigError

EVAL_KEYS = {"policy", "robots", "episodes", "seed", "elratio_mean", "elratio_std", "reward_mean",
             "collisions_mean", "block_collisions_mean", "success_rate", "planning_ms_per_decision"}




def has_policy(name: str) -> bool:
    from policies import policy_class

    try:
        policy_class(name)
    except ImportError:
        return False
    return True


@pytest.mark.procs
def test_eval_writes_contract_json(tmp_path: Path) -> None:
    out = tmp_path / "eval.json"
    r = swarm("eval", "--policy", "random", "--robots", "4", "--episodes", "12", "--seed", "3",
              "--batch", "5", "--static", "--json", str(out))
    assert r.returncode == 0, r.stderr
    assert "random" in r.stdout and "elratio" in r.stdout  # the rich results table
    data = json.loads(out.read_text())
    assert EVAL_KEYS <= set(data)
    assert (data["policy"], data["robots"], data["episodes"], data["seed"]) == ("random", 4, 12, 3)
    assert data["dynamic"] is False
    assert 0.0 < data["elratio_mean"] <= 1.0 and data["elratio_std"] >= 0.0
    assert 0.0 <= data["success_rate"] <= 1.0
    assert data["collisions_mean"] >= data["block_collisions_mean"] >= 0.0
    assert data["planning_ms_per_decision"] >= 0.0
    assert not list(tmp_path.glob(".*.tmp"))  # the atomic writer cleaned up


@pytest.mark.procs
def test_eval_is_deterministic_and_frontier_beats_random(tmp_path: Path) -> None:
    names = ["random"] + (["nearest-frontier"] if has_policy("nearest-frontier") else [])
    runs = []
    for k in range(2):
        out = tmp_path / f"e{k}.json"
        r = swarm("eval", "--policy", ",".join(names), "--episodes", "6", "--seed", "1",
                  "--json", str(out))
        assert r.returncode == 0, r.stderr
        runs.append(json.loads(out.read_text()))
    first = runs[0]["results"] if len(names) > 1 else [runs[0]]
    second = runs[1]["results"] if len(names) > 1 else [runs[1]]
    for a, b in zip(first, second, strict=True):
        assert a["elratio_mean"] == b["elratio_mean"] and a["reward_mean"] == b["reward_mean"]
    if len(names) > 1:
        assert first[1]["elratio_mean"] > first[0]["elratio_mean"]


@pytest.mark.procs
def test_eval_compares_policies_paired_and_writes_every_episode(tmp_path: Path) -> None:
    """Several policies, a checkpoint named per policy (NAME=FILE), each policy's elratio minus
    the first's paired over the same episodes (table and JSON), and the per-episode CSV that
    pairing is made from."""
    ckpt, js, eps = ROOT / "checkpoints" / "commnet.pt", tmp_path / "e.json", tmp_path / "e.csv"
    r = swarm("eval", "--policy", "nearest-frontier,commnet,random", "--checkpoint",
              f"commnet={ckpt}", "--robots", "4", "--episodes", "5", "--seed", "3",
              "--episodes-csv", str(eps), "--json", str(js))
    assert r.returncode == 0, r.stderr
    assert "Δ elratio ± se" in r.stdout and "minus nearest-frontier's" in r.stdout
    res = json.loads(js.read_text())["results"]
    assert res[1]["checkpoint"].endswith("commnet.pt") and "elratio_paired" not in res[0]
    with open(eps, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(x["policy"], int(x["episode"])) for x in rows[:6]] == [
        *(("nearest-frontier", e) for e in range(5)), ("commnet", 0)]
    el = {p: np.array([float(x["elratio"]) for x in rows if x["policy"] == p])
          for p in ("nearest-frontier", "commnet", "random")}
    for k, name in ((1, "commnet"), (2, "random")):
        assert el[name].mean() == pytest.approx(res[k]["elratio_mean"])
        diff = el[name] - el["nearest-frontier"]
        assert res[k]["elratio_paired"]["vs"] == "nearest-frontier"
        assert res[k]["elratio_paired"]["mean"] == pytest.approx(diff.mean())
        assert res[k]["elratio_paired"]["se"] == pytest.approx(diff.std(ddof=1) / 5 ** 0.5)


def test_a_reader_that_goes_away_is_said_not_a_silent_exit_1() -> None:
    """`swarm eval ... | true`: rich's own answer to a closed stdout was a silent exit 1 (for
    `replay --verify`, the status of a divergence); it is one line and 141, as a shell reports
    a SIGPIPE, as `swarm run --headless | head` already said."""
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", "eval", "--policy", "random",
                             "--robots", "2", "--episodes", "2"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    proc.stdout.close()  # (before it prints: its results table meets a closed pipe)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 141, err
    assert err.strip().splitlines()[-1] == "swarm: stdout was closed (its reader went away)", err


def test_a_paired_difference_of_one_episode_says_it_has_no_standard_error() -> None:
    """UA pass 61: `swarm eval --episodes 1` with two policies printed "-0.0081 ± nan"."""
    import numpy as np

    from swarm.common.report import paired, paired_cell

    assert paired_cell(*paired(np.array([0.5]), np.array([0.6]))) == "-0.1000 (1 episode: no se)"
    assert paired_cell(*paired(np.array([0.5, 0.7]), np.array([0.6, 0.6]))) == "+0.0000 ± 0.1000"
    from swarm.common.report import counted  # (UA pass 66: "1 episodes", "1 bad records")

    assert [counted(n, "bad record") for n in (0, 1, 2)] == ["0 bad records", "1 bad record",
                                                             "2 bad records"]


@pytest.mark.parametrize("args", [
    ["eval", "--episodes", "-3", "--policy", "random"],
    ["eval", "--policy", "no-such-policy"],
    ["eval", "--episodes", "many"],
    ["eval", "--comm-range", "-1"],
    ["eval", "--policy", "random", "--comm-range", "1e300"],  # (overflowed in the radio)
    ["eval", "--policy", "random", "--add-every", "9" * 400],  # (overflowed a float)
    ["eval", "--policy", "random", "--episodes", "9" * 400],  # (broke the progress bar)
    ["eval", "--policy", "random", "--episodes", "9223372036854775808"],  # (ran until killed)
    ["eval", "--policy", "random", "--config", "{tmp}/float_episodes.toml"],  # (1e300 too)
    ["eval", "--policy", "random", "--vision", "4"],
    ["eval", "--policy", "random", "--checkpoint", "x.pt"],
    ["eval", "--policy", "random", "--config", "{tmp}/missing.toml"],
    ["eval", "--policy", "random", "--config", "{tmp}/malformed.toml"],
    ["bench", "env", "--batch", "0,4"],
    ["bench", "policy", "--policies", "random,bogus"],
    ["bench", "policy", "--policies", "random", "--checkpoint", "commattn=x.pt"],
    ["bench", "policy", "--policies", "commattn", "--checkpoint", "x.pt"],
    ["bench", "swarm", "--repeats", "0"],
    ["bench", "swarm", "--repeats", "2", "--delivery", "radio", "--robots", "0"],
    ["repro", "fig99", "--out", "{tmp}/o"],  # fig9 became an item (issue 16)
    ["repro", "fig5", "--out", "{tmp}/o", "--add-every", "40", "--policies", "random"],
    ["eval", "--policy", "random", "--static", "--add-every", "5"],
    ["eval", "--policy", "random", "--bandwidth", "0", "--overflow", "drop"],  # "no cap"
    ["eval", "--policy", "commattn,commnet", "--checkpoint", "a.pt"],  # whose is it?
    ["eval", "--policy", "commattn", "--checkpoint", "a.pt", "--checkpoint", "commattn=b.pt"],
    ["eval", "--policy", "commattn", "--checkpoint", "commnet=checkpoints/commnet.pt"],
    ["train", "--out", "{tmp}/malformed.toml/run"],  # (a path under a file: errno, exit 1)
    ["train", "--out", "/proc/swarm-train"],  # (the probe writes: root may write anywhere)
    ["repro", "fig8", "--out", "{tmp}/o", "--json", "{tmp}/o/fig8.json"],  # (overwrote it)
    ["frobnicate"],
])
@pytest.mark.procs
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, args: list[str],
                                          capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "malformed.toml").write_text("[world\nn_robots = = 3\n")
    (tmp_path / "float_episodes.toml").write_text("[eval]\nepisodes = 1e300\n")
    r = swarm_here(*(a.replace("{tmp}", str(tmp_path)) for a in args), capsys=capsys)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.rstrip("\n").splitlines()  # (a progress display closed by the error
    assert len(lines) == 1 and lines[0].startswith("swarm: error: "), r.stderr  # left a line)
    assert "Traceback" not in r.stdout


@pytest.mark.procs
@pytest.mark.parametrize("policy", [[], ["--policy", "commattn"]], ids=["default", "given"])
def test_a_checkpoint_for_a_name_that_is_no_policy_says_so(
        policy: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """`--checkpoint NAME=FILE` with an unknown NAME is refused as no policy (it was taken for a
    file and "not found"); a policy not evaluated is named as not among --policy."""
    r = swarm_here("eval", *policy, "--checkpoint", "foo=checkpoints/commattn.pt", capsys=capsys)
    assert r.returncode == 2 and r.stderr.strip() == (
        "swarm: error: --checkpoint foo=...: 'foo' is not a policy (learned ones: bicnet, "
        "commattn, commnet, vain)"), r.stderr
    r = swarm_here("eval", *policy, "--checkpoint", "commnet=checkpoints/commnet.pt",
                   capsys=capsys)
    assert r.returncode == 2 and "'commnet' is not among --policy" in r.stderr, r.stderr


@pytest.mark.procs
def test_config_file_unknown_key_and_table_rejected(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    for body, word in [("[world]\nn_robotz = 3\n", "n_robotz"),
                       ("[eval]\nepisodez = 3\n", "episodez"),
                       ("[wrold]\nn_robots = 3\n", "wrold")]:
        cfg = tmp_path / "exp.toml"
        cfg.write_text(body)
        r = swarm_here("eval", "--policy", "random", "--episodes", "2", "--config", str(cfg),
                       capsys=capsys)
        assert r.returncode == 2
        assert len(r.stderr.strip().splitlines()) == 1 and word in r.stderr


@pytest.mark.procs
def test_config_file_applies_and_flags_override(tmp_path: Path) -> None:
    cfg = tmp_path / "exp.toml"
    cfg.write_text('[world]\nn_robots = 3\ndynamic = false\n\n'
                   '[eval]\npolicy = "random"\nepisodes = 5\nseed = 9\n')
    out = tmp_path / "e.json"
    r = swarm("eval", "--config", str(cfg), "--episodes", "4", "--json", str(out))
    assert r.returncode == 0, r.stderr
    data = json.loads(out.read_text())
    assert (data["robots"], data["episodes"], data["seed"], data["dynamic"]) == (3, 4, 9, False)
    # what made it: the whole world (the file's too), faults, command and software
    assert data["world"]["n_robots"] == 3 and data["world"]["height"] == 20
    assert data["faults"] is None and data["command"].startswith("swarm eval --config")
    prov = data["provenance"]
    assert prov["versions"]["commattn-swarm"] and prov["versions"]["numpy"] == np.__version__


def test_eval_json_records_the_settings_that_change_its_figures(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """UA 75: `[eval] tick_timeout = 0.3` changed elratio under a latency but was recorded
    nowhere, nor `greedy = false` or the fault seed (`[faults] seed`); the JSON now holds them
    and the whole fault plan (burst and seed too, which the `faults` line leaves out)."""
    cfg = tmp_path / "e.toml"
    cfg.write_text('[world]\nn_robots = 3\nhorizon = 10\n[eval]\npolicy = "random"\n'
                   'episodes = 2\ntick_timeout = 0.3\ngreedy = false\n'
                   '[faults]\nlatency = "250ms"\nbandwidth = "60B/s"\nburst = 240\nseed = 7\n')
    out = tmp_path / "e.json"
    r = swarm_here("eval", "--config", str(cfg), "--json", str(out), capsys=capsys)
    assert r.returncode == 0, r.stderr
    data = json.loads(out.read_text())
    assert (data["greedy"], data["tick_timeout"]) == (False, 0.3)
    plan = data["fault_plan"]
    assert plan["seed"] == 7 and plan["default"]["latency_ms"] == 250
    assert plan["default"]["burst"] == 240


def test_every_episodes_csv_column_is_documented(capsys: pytest.CaptureFixture[str]) -> None:
    """UA 75: `repeat_ratio` was documented nowhere and the CSV's `reward` unit unsaid (the
    README's tables say "reward / robot"): the README names every column by its CSV name next
    to `--episodes-csv`, and `--help` says the reward is per robot."""
    from swarm.cli import main
    from world.core import METRIC_NAMES

    readme = " ".join((ROOT / "README.md").read_text().split())
    said = readme[readme.index("`--episodes-csv F` writes"):][:1200]
    for column in ("policy", "episode", *METRIC_NAMES):
        assert f"`{column}`" in said, (column, said)
    assert "return per robot" in said and "`repeat_ratio`, the share of robot-steps" in said
    with pytest.raises(SystemExit):
        main(["eval", "--help"])
    assert "episode return per robot" in " ".join(capsys.readouterr().out.split())


@pytest.mark.procs
def test_eval_warns_that_it_plays_without_the_process_faults_of_a_shared_file(
        tmp_path: Path) -> None:
    """A `[faults]` table shared with `swarm run` (UA pass: its crash was silently ignored): one
    warning line, and the link faults still apply."""
    cfg = tmp_path / "f.toml"
    cfg.write_text('[world]\nn_robots = 3\nhorizon = 10\n\n'
                   '[faults]\nloss = 0.2\ncrash = ["1@3"]\nhang = ["2@4"]\n')
    out = tmp_path / "e.json"
    r = swarm("eval", "--config", str(cfg), "--policy", "random", "--episodes", "1", "--json",
              str(out))
    assert r.returncode == 0, r.stderr
    warned = [line for line in r.stderr.splitlines() if "warning" in line]
    assert warned == ["swarm: warning: [faults] crash, hang are the swarm's process faults (swarm "
                      "run); the batched evaluation plays without them"], r.stderr
    faults = json.loads(out.read_text())["faults"]
    assert "loss" in faults and "crash" not in faults, faults


def test_the_help_states_defaults_and_what_it_names(monkeypatch: pytest.MonkeyPatch) -> None:
    """UA pass: help without the defaults of --seed, --fault-seed, record --wait/--flush and the
    learner's loss flags; eval's `all` unexplained; a module that does not exist; a hint planner
    left out; `swarm fault` saying "at once" of flags that take ROBOT@TICK; experiment --resume
    and the learner's description not saying what they do; the router's Zenoh mode."""
    import argparse

    from swarm.cli import build_parser

    monkeypatch.setenv("COLUMNS", "2000")  # (no line broken at a hyphen)
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))

    def text(command: str) -> str:
        return " ".join(sub.choices[command].format_help().split())

    for command in ("run", "eval", "train", "learner", "world"):
        assert "noise (default 0)" in text(command), command
    assert "seed of the fault draws (default: the episode seed, --seed)" in text("eval")
    assert "seed of the fault draws (default: the run's --seed)" in text("fault")
    assert "for the world (default 30)" in text("record") and "(default 0.5)" in text("record")
    learner = text("learner")
    for flag in ("--lr TRAIN_LR Adam learning rate (default 0.003)", "alpha (default 0.03)",
                 "discount (default 1)", "entropy bonus (default 0.01)",
                 "torch threads (default 1)"):
        assert flag in learner, flag
    assert "write OUT/checkpoint.pt (atomically) after each update" in learner
    assert "'all' (the four baselines: random, nearest-frontier, coordinated-frontier, " \
        "cost-utility;" in text("eval")
    train = text("train")
    assert "swarm.learn.parallel" in train and "swarm.train_parallel" not in train
    assert '"chain-plan" (its move, ours)' in train
    fault = text("fault")
    assert "ROBOT@TICK at run tick TICK, ROBOT alone at once" in fault
    assert "--crash ROBOT[@TICK]" in fault and "or at once with ROBOT alone" in fault
    resume = text("experiment")
    assert "same episodes and seeds" not in resume and "holds this sweep's world, [run]" in resume
    # UA pass 60: the router's help said the shared "(default peer)" of its mode
    assert "Zenoh mode (default router)" in text("router")
    assert "Zenoh mode (default peer)" in text("robot")


def test_each_command_s_pace_help_states_its_own_default(monkeypatch: pytest.MonkeyPatch) -> None:
    """UA pass: `swarm run` and `swarm world` shared a --pace help naming a dashboard, a
    --headless and a --json-only `swarm world` does not have (and no command has)."""
    import argparse

    from swarm.cli import build_parser

    monkeypatch.setenv("COLUMNS", "2000")
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))

    def pace(command: str) -> str:
        help_text = " ".join(sub.choices[command].format_help().split())
        return help_text.split("--pace HZ cap ticks/s so the run can be watched (default: ",
                               1)[1].split(")", 1)[0]

    assert pace("world") == "unlimited"
    assert pace("run") == ("8 when the live dashboard is on a terminal; unlimited with "
                           "--headless or when stdout is not a terminal")


def test_merge_precedence_in_process(tmp_path: Path) -> None:
    cfg = tmp_path / "exp.toml"
    cfg.write_text('[world]\nvision = 7\ncomm_range = 3.5\n[eval]\nbatch = 17\n')
    tables = file_tables(str(cfg))
    import argparse

    args = argparse.Namespace(world_robots=None, dynamic=None, world_add_every=None, vision=None,
                              comm_range=float("inf"), horizon=None, sense=True)
    world = world_config(args, tables)
    assert (world.vision, world.comm_range, world.explore_mode) == (7, float("inf"), "sense")
    ev = merged(EvalConfig, tables["eval"], {"episodes": 3, "batch": None}, "[eval]")
    assert (ev.batch, ev.episodes, ev.policy) == (17, 3, "nearest-frontier")
    with pytest.raises(ConfigError):
        merged(EvalConfig, {}, {"episodes": 0}, "[eval]")


def test_dynamic_only_flags_refused_on_a_static_map() -> None:
    """`--static --add-every 5` did nothing; now it is a one-line error (the file's static too)."""
    import argparse

    def args(**kw: object) -> argparse.Namespace:
        base = {"world_robots": None, "dynamic": None, "world_add_every": None, "vision": None,
                "comm_range": None, "horizon": None, "sense": None}
        return argparse.Namespace(**{**base, **kw})

    with pytest.raises(ConfigError, match="--add-every has no effect on a static map"):
        world_config(args(dynamic=False, world_add_every=5), {})
    with pytest.raises(ConfigError, match="--dynamic-blocks has no effect"):
        world_config(args(dynamic_blocks=20), {"world": {"dynamic": False}})
    assert world_config(args(world_add_every=5), {}).add_every == 5  # dynamic: fine
    assert not world_config(args(dynamic=False), {"world": {"add_every": 2}}).dynamic  # file: kept


@pytest.mark.procs
def test_bench_env_tiny(tmp_path: Path) -> None:
    out = tmp_path / "env.json"
    r = swarm("bench", "env", "--batch", "1,4", "--repeats", "2", "--episodes", "1",
              "--robots", "3", "--json", str(out))
    assert r.returncode == 0, r.stderr
    data = json.loads(out.read_text())
    assert set(data["agent_steps_per_s"]) == {"1", "4"}
    assert all(v > 0 for v in data["agent_steps_per_s"].values())
    assert data["robots"] == 3 and "agent-steps/s" in r.stdout


@pytest.mark.procs
def test_bench_policy_tiny(tmp_path: Path) -> None:
    out = tmp_path / "pol.json"
    r = swarm("bench", "policy", "--policies", "random", "--decisions", "8", "--warmup", "0",
              "--json", str(out))
    assert r.returncode == 0, r.stderr
    row = json.loads(out.read_text())["rows"][0]
    assert row["policy"] == "random" and row["decisions"] == 8
    assert 0 <= row["min_ms"] <= row["median_ms"] <= row["p90_ms"] <= row["max_ms"]


@pytest.mark.procs
def test_bench_policy_one_robot_times_a_robots_decision(tmp_path: Path) -> None:
    """`--one-robot`: a chained learned policy and a planner, each robot with its own policy."""
    out = tmp_path / "one.json"
    r = swarm("bench", "policy", "--policies", "commattn,nearest-frontier", "--decisions", "12",
              "--warmup", "0", "--robots", "3", "--one-robot", "--json", str(out),
              "--checkpoint", f"commattn={ROOT / 'checkpoints' / 'commattn.pt'}")
    assert r.returncode == 0, r.stderr
    data = json.loads(out.read_text())
    assert data["one_robot"] is True and "one robot" in r.stdout
    assert data["checkpoints"] == {"commattn": "checkpoints/commattn.pt"}  # (as recorded)
    for row in data["rows"]:
        assert row["decisions"] == 12 and row["bar_ms"] is None
        assert 0 < row["min_ms"] <= row["median_ms"] <= row["max_ms"]


@pytest.mark.procs
def test_repro_all_tiny_writes_every_file(tmp_path: Path) -> None:
    out = tmp_path / "repro"
    r = swarm("repro", "all", "--out", str(out), "--policies", "random", "--episodes", "3",
              "--robots", "2,4", "--add-every", "3,6", "--decisions", "5", "--seed", "7")
    assert r.returncode == 0, r.stderr
    for item in ("table1", "fig4", "fig5"):
        for ext in ("csv", "md", "png", "json"):
            assert (out / f"{item}.{ext}").stat().st_size > 0, (item, ext)
        assert (out / f"{item}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        md = (out / f"{item}.md").read_text()
        assert "swarm repro all" in md and "seed 7" in md and "|" in md
    rows = list(csv.DictReader((out / "fig4.csv").open()))
    assert [int(r["robots"]) for r in rows] == [2, 4]
    assert all(0 < float(r["elratio_mean"]) <= 1 for r in rows)
    fig5 = json.loads((out / "fig5.json").read_text())
    assert [r["add_every"] for r in fig5["rows"]] == [3, 6]
    table1 = list(csv.DictReader((out / "table1.csv").open()))
    assert table1[0]["policy"] == "random" and float(table1[0]["mean_ms"]) >= 0


def _render(table: object) -> str:
    console = Console(record=True, width=200, file=StringIO())
    console.print(table)
    return console.export_text()


def test_renderers_show_the_figures(capsys: pytest.CaptureFixture[str]) -> None:
    s = {"policy": "nearest-frontier", "elratio_mean": 0.8531, "elratio_std": 0.0412,
         "reward_mean": -71.25, "reward_std": 20.0, "collisions_mean": 4.5,
         "block_collisions_mean": 0.25, "success_rate": 0.375, "planning_ms_per_decision": 0.1234}
    text = _render(eval_table([s], "eval test"))
    for x in ("nearest-frontier", "0.853 ± 0.041", "37.5%", "0.123", "eval test"):
        assert x in text
    for bad, why in ((["certs", "--out", str(Path(__file__)) + "/x", "--robots", "1"],
                      "which is not a directory"),):  # (a path under a file: errno, exit 1)
        r = swarm_here(*bad, capsys=capsys)
        assert r.returncode == 2 and why in r.stderr and r.stderr.count("\n") == 1, r.stderr
    # on an 80-column terminal every figure stays whole (it was `0.…`), the sd left out
    t = {**s, "policy": "coordinated-frontier", "reward_mean": -295.67, "collisions_mean": 87.0,
         "block_collisions_mean": 84.33, "elratio_paired": {"vs": "x", "mean": -0.3225,
                                                            "se": 0.0088}}
    console = Console(record=True, width=80, file=StringIO())
    console.print(eval_table([t, t], "eval test", width=console.width))
    text = console.export_text()
    for x in ("coordinated-frontier", "0.853", "-295.7", "87.00", "84.33", "37.5%", "0.123",
              "-0.3225±0.0088", "means only"):
        assert x in text, text
    assert "…" not in text
    console = Console(record=True, width=110, file=StringIO())  # (too narrow with a Δ column)
    console.print(eval_table([t, t], "eval test", width=console.width))
    text = console.export_text()
    assert "…" not in text and "-0.3225±0.0088" in text, text
    from swarm.learn.evaluate import EvalResult  # a run stopped before any episode ended
    from world.config import WorldConfig

    none = EvalResult.none("commattn", 0, WorldConfig()).summary(WorldConfig())
    for w in (80, 200):
        text = _render(eval_table([none], "stopped", width=w))
        assert "commattn" in text and "0.0%" not in text and "0.000" not in text, text

    env = {"robots": 10, "horizon": 30, "repeats": 3, "bar": {"batch": 1024,
                                                              "agent_steps_per_s": 4e6},
           "rows": [{"batch": 1024, "agent_steps_per_s": 4.5e6, "min": 4e6, "max": 5e6,
                     "agent_steps_per_cpu_s": 4.6e6, "step_ms": 2.2, "reset_ms_per_episode": 1.9}]}
    text = _render(env_bench_table(env))
    assert "4,500,000" in text and "yes" in text

    pol = {"robots": 10, "decisions": 50, "rows": [
        {"policy": "cost-utility", "median_ms": 3.5, "p90_ms": 5.0, "mean_ms": 3.7, "std_ms": 0.5,
         "bar_ms": 3.0, "meets_bar": False}]}
    text = _render(policy_bench_table(pol))
    assert "cost-utility" in text and "3.500" in text and "NO" in text

    t1 = [{"policy": "nearest-frontier", "mean_ms": 0.4, "std_ms": 0.1, "median_ms": 0.3,
           "p90_ms": 0.6, "paper_mean_ms": 35.0, "paper_std_ms": 5.0, "robots": 3},
          {"policy": "random", "mean_ms": 0.01, "std_ms": 0.0, "median_ms": 0.01, "p90_ms": 0.02,
           "paper_mean_ms": None, "paper_std_ms": None, "robots": 3}]
    text = _render(table1_table(t1))
    assert "35 ± 5" in text and "random" in text and "3 robots" in text  # (said 10 always)

    rows = [{"policy": p, "robots": n, "elratio_mean": 0.5 + n / 100, "elratio_std": 0.01}
            for p in ("random", "nearest-frontier") for n in (2, 4)]
    text = _render(sweep_table("Fig. 4", "robots", rows))
    assert "0.540 ± 0.010" in text and "nearest-frontier" in text


@pytest.mark.procs
def test_repro_table2_and_fig8_with_a_learned_policy(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A real (tiny) training run's checkpoint and curve feed Table 2 and Fig. 8."""
    run = tmp_path / "run"
    r = swarm("train", "--policy", "vain", "--out", str(run), "--epochs", "1", "--updates", "3",
              "--batch", "4", "--val-episodes", "0", "--threads", "1", "--seed", "3")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "repro"
    r = swarm("repro", "all", "--out", str(out), "--policies", "vain,random",
              "--checkpoint", f"vain={run / 'checkpoint.pt'}", "--curve",
              f"vain={run / 'curve.csv'}", "--table2-episodes", "6", "--episodes", "2",
              "--robots", "3", "--add-every", "3", "--decisions", "3", "--seed", "5")
    assert r.returncode == 0, r.stderr
    # UA pass 61: the items its --policies cannot serve were left out without a word
    assert ("swarm: warning: repro leaves out fig9 (neither commnet nor commattn among "
            "--policies); fig10 (not commattn among --policies); fig11 (not commattn among "
            "--policies); comm (not commattn among --policies): run `swarm repro ITEM` on its own, "
            "or add the policy to --policies") in r.stderr, r.stderr
    rows = json.loads((out / "table2.json").read_text())["rows"]
    assert [row["policy"] for row in rows] == ["vain", "random"]
    assert all(row["episodes"] == 6 and 0 < row["elratio_mean"] <= 1 for row in rows)
    assert rows[0]["paper_elratio_pct"] == 90.2 and rows[1]["paper_reward"] is None
    assert "90.2" in (out / "table2.md").read_text()
    assert rows[0]["first_minus_elratio"] == 0 and rows[1]["first_minus_elratio_se"] > 0
    assert "vain - this (paired)" in (out / "table2.md").read_text()
    md = (out / "table2.md").read_text()  # its words are on the rows it has, no others
    assert not any(w in md for w in ("team-beam", "chain-plan", "oracle", "central", "gap",
                                     "marked *")), md
    fig8 = list(csv.DictReader((out / "fig8.csv").open()))
    assert [int(row["update"]) for row in fig8] == [3] and fig8[0]["policy"] == "vain"
    assert (out / "fig8.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bad = swarm_here("repro", "fig8", "--out", str(out), "--policies", "vain", "--curve",
                     f"vain={tmp_path / 'missing.csv'}", capsys=capsys)
    assert bad.returncode == 2 and "no training curve" in bad.stderr


@pytest.mark.procs
def test_repro_fig9_writes_a_row_per_policy_vision_and_range(tmp_path: Path) -> None:
    """Fig. 9 with the shipped CommNet (vision 5); visions without a checkpoint are named. A
    config's world vision and comm range (for other items) are not used and said so: with
    vision 7 it took the shipped vision-5 checkpoint for vision 7 and failed."""
    cfg = tmp_path / "f9.toml"
    cfg.write_text("[world]\nvision = 7\ncomm_range = 3.0\n[repro]\nfig9_episodes = 4\n")
    out = tmp_path / "repro"
    r = swarm("repro", "fig9", "--out", str(out), "--config", str(cfg), "--policies", "commnet",
              "--seed", "1")
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader((out / "fig9.csv").open()))
    have = [v for v in (3, 5, 7, 9)
            if v == 5 or (ROOT / "checkpoints" / "vision" / f"commnet_v{v}.pt").is_file()]
    assert [(row["policy"], int(row["vision"])) for row in rows] == [
        ("commnet", v) for v in have for _ in range(10)]
    assert [row["comm_range"] for row in rows][9] == "inf"
    assert all(0 <= float(row["success_rate"]) <= 1 and 0 < float(row["elratio_mean"]) <= 1
               for row in rows)
    md = (out / "fig9.md").read_text()
    assert all(f"commnet v={v}" in md for v in (3, 7, 9) if v not in have)
    assert "world's vision 7 and comm range 3 (for the other items of the command) are not " \
        "used here" in md
    assert (out / "fig9.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_repro_fig9_refuses_a_wrong_checkpoint_before_any_point(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """UA pass 61: CommAttn's checkpoint was loaded only after CommNet's whole sweep (minutes at
    the default 1000 episodes a point, then thrown away); now before the first evaluation."""
    from swarm.cli import main
    from swarm.studies import fig9

    evaluated: list[str] = []
    real = fig9.evaluate
    monkeypatch.setattr(fig9, "evaluate", lambda *a, **k: evaluated.append("x") or real(*a, **k))
    cfg = tmp_path / "f9.toml"
    cfg.write_text("[repro]\nfig9_episodes = 1\n")
    code = main(["repro", "fig9", "--out", str(tmp_path / "o"), "--config", str(cfg),
                 "--checkpoint", f"commattn={ROOT / 'checkpoints' / 'commnet.pt'}"])
    err = capsys.readouterr().err
    assert code == 2 and "holds policy 'commnet', not 'commattn'" in err, err
    assert evaluated == [] and not (tmp_path / "o" / "fig9.csv").exists()


def test_fig9_without_vision_checkpoints_warns_on_stderr(tmp_path: Path, capsys) -> None:
    """UA pass: with checkpoints/vision/ missing, `repro fig9` wrote a partial figure, exit 0,
    its only trace a line in fig9.md; one warning line on stderr names what was left out."""
    from swarm.studies.fig9 import fig9
    from world.config import WorldConfig

    res = fig9(WorldConfig(), tmp_path, "test", seed=1, episodes=1, policies=("commnet",),
               visions=(3, 5), ranges=(1.0,), batch=1, vision_dir=tmp_path / "none",
               checkpoints={"commnet": str(ROOT / "checkpoints" / "commnet.pt")})
    assert [r["vision"] for r in res["rows"]] == [5]
    warning = capsys.readouterr().err.strip().splitlines()
    assert len(warning) == 1 and "fig9 leaves out commnet v=3" in warning[0], warning
    assert str(tmp_path / "none") in warning[0]


@pytest.mark.procs
def test_repro_comm_compares_learned_frontier_and_a_perfect_radio(tmp_path: Path) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text("[repro]\ncomm_episodes = 1\n")  # (one: the columns, not the figures)
    r = swarm("repro", "comm", "--out", str(tmp_path), "--config", str(cfg), "--seed", "2")
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader((tmp_path / "comm.csv").open()))
    assert len(rows) == 12 * 3 and {row["policy"] for row in rows} == {
        "commattn", "coordinated-frontier", "central"}
    small = [row for row in rows if row["size"] == "20x20"]
    central = {float(row["elratio_mean"]) for row in small if row["policy"] == "central"}
    assert len(small) == 10 * 3 and len(central) == 1  # a perfect radio: no fault changes it
    ref = {row["condition"]: float(row["elratio_mean"]) for row in rows
           if row["policy"] == "central"}
    for row in rows:
        assert float(row["gap_to_central"]) == pytest.approx(
            ref[row["condition"]] - float(row["elratio_mean"]))
    big = [row for row in rows if row["size"] == "40x40"]
    assert sorted({(row["robots"], row["horizon"]) for row in big}) == [("20", "60"), ("50", "24")]
    mean = {(row["policy"], row["condition"]): float(row["elratio_mean"]) for row in rows}
    for row in rows:  # CommAttn's paired lead over the same episodes: the difference of means
        assert float(row["first_minus_elratio"]) == pytest.approx(
            mean["commattn", row["condition"]] - float(row["elratio_mean"]), abs=1e-9)
    assert "commattn - central (paired)" in (tmp_path / "comm.md").read_text()
    tuned = "checkpoints/scale/commattn_40x40_n20.pt"  # (relative: no machine's directories)
    assert {row["checkpoint"] for row in big if row["policy"] == "commattn"} == {tuned}


@pytest.mark.procs
def test_a_killed_repro_comm_resumes_to_the_same_files(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`swarm repro comm` SIGKILLed mid-study, then `--resume`d: the cells it had made are kept
    (not played again) and the study's CSV equals an uninterrupted run's; a resume with other
    settings, or with nothing to resume, is one line, exit 2."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[repro]\ncomm_episodes = 2\n")
    args = ["repro", "comm", "--config", str(cfg), "--seed", "2", "--batch", "2",
            "--comm-policies", "nearest-frontier,random"]
    whole = subprocess.Popen([sys.executable, "-m", "swarm.cli", *args, "--out",
                              str(tmp_path / "whole")], cwd=ROOT, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    kept: dict = {}  # the uninterrupted run's cells, its partial file as last seen (for the end)
    try:
        while whole.poll() is None:
            try:
                kept = json.loads((tmp_path / "whole" / "comm.partial.json").read_text())["cells"]
            except (OSError, ValueError):
                pass
            time.sleep(0.05)
    finally:
        if whole.poll() is None:
            whole.kill()
    assert whole.wait(timeout=300) == 0
    partial = tmp_path / "cut" / "comm.partial.json"
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", *args, "--out",
                             str(tmp_path / "cut")], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not partial.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.01)
        proc.kill()
    finally:
        proc.wait(timeout=30)
    made = json.loads(partial.read_text())["cells"]
    assert 1 <= len(made) < 24 and not (tmp_path / "cut" / "comm.csv").exists()
    other = swarm_here(*args[:-2], "--comm-policies", "nearest-frontier", "--out",
                       str(tmp_path / "cut"), "--resume", capsys=capsys)
    assert other.returncode == 2 and other.stderr.strip().splitlines() == [
        f"swarm: error: --resume: the interrupted comm in {tmp_path / 'cut'} was made with "
        "other policies; give its settings, or drop --resume to start again"], other.stderr
    more = swarm_here(*args, "--comm-episodes", "3", "--out", str(tmp_path / "cut"), "--resume",
                      capsys=capsys)
    assert more.returncode == 2 and "was made with other episodes;" in more.stderr, more.stderr
    every = swarm_here("repro", "all", *args[2:], "--out", str(tmp_path / "cut"), "--resume",
                       capsys=capsys)
    assert every.returncode == 2 and "goes on with an interrupted comm, alone" in every.stderr
    none = swarm_here(*args, "--out", str(tmp_path / "none"), "--resume", capsys=capsys)
    assert none.returncode == 2 and "no interrupted comm" in none.stderr, none.stderr
    held = json.loads(partial.read_text())  # a cell cut short (hand-edited, or not ours)
    next(iter(held["cells"].values()))["elratio"].pop()
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "comm.partial.json").write_text(json.dumps(held))
    bad = swarm_here(*args, "--out", str(tmp_path / "bad"), "--resume", capsys=capsys)
    assert bad.returncode == 2 and bad.stderr.strip().splitlines() == [
        f"swarm: error: --resume: {tmp_path / 'bad' / 'comm.partial.json'} is not a comm "
        "study's cells"], bad.stderr
    r = swarm(*args, "--out", str(tmp_path / "cut"), "--resume")
    assert r.returncode == 0, r.stderr
    assert f"resumes with {len(made)} of 24 cells made" in r.stderr
    assert not partial.exists()  # the item's files hold every cell now
    assert (tmp_path / "cut" / "comm.csv").read_text() == \
        (tmp_path / "whole" / "comm.csv").read_text()
    # a kept cell is read, not played again: the uninterrupted run's cells kept (any missing
    # from its last partial seen are played), one of them marked
    cell = next(iter(made))
    held["cells"] = {**kept, cell: {**made[cell], "summary": {**made[cell]["summary"],
                                                              "elratio_mean": 0.123456}}}
    (tmp_path / "bad" / "comm.partial.json").write_text(json.dumps(held))
    assert swarm(*args, "--out", str(tmp_path / "bad"), "--resume").returncode == 0
    rows = list(csv.DictReader((tmp_path / "bad" / "comm.csv").open()))
    assert [float(row["elratio_mean"]) for row in rows
            if f"{row['condition']} | {row['policy']}" == cell] == [0.123456]


def test_repro_comm_without_commattn_needs_no_commattn_checkpoint(tmp_path: Path,
                                                                   monkeypatch) -> None:
    """UA pass: `repro comm --comm-policies coordinated-frontier,nearest-frontier` demanded a
    CommAttn checkpoint it never used; with none shipped it runs."""
    from swarm.common import policy_spec
    from swarm.studies.repro import ReproConfig, prepare, run
    from world.config import WorldConfig

    monkeypatch.setattr(policy_spec, "SHIPPED", tmp_path / "none")  # no checkpoint shipped
    cfg = ReproConfig(out=str(tmp_path), comm_episodes=1, batch=1,
                      comm_policies=("coordinated-frontier", "nearest-frontier"))
    items = prepare(["comm"], WorldConfig(), cfg)
    res = run(items, WorldConfig(), cfg, "test", prepared=True)
    assert {row["policy"] for row in res["comm"]["rows"]} == set(cfg.comm_policies)


@pytest.mark.procs
def test_repro_comm_takes_the_policies_and_checkpoints_it_is_given(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`--comm-policies` chooses the study's policies (the first paired against the others) and a
    given checkpoint runs on both map sizes; a bad name is a one-line error."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[repro]\ncomm_episodes = 1\n")  # (one: the columns, not the figures)
    bad = swarm_here("repro", "comm", "--out", str(tmp_path), "--config", str(cfg),
                     "--comm-policies", "nearest-frontier,nope", capsys=capsys)
    assert bad.returncode != 0 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
    mine = "checkpoints/commattn_nomemory.pt"
    r = swarm("repro", "comm", "--out", str(tmp_path), "--config", str(cfg), "--seed", "2",
              "--comm-policies", "nearest-frontier,commattn", "--checkpoint", f"commattn={mine}")
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader((tmp_path / "comm.csv").open()))
    assert [row["policy"] for row in rows[:2]] == ["nearest-frontier", "commattn"]
    assert len(rows) == 12 * 2
    assert {row["checkpoint"] for row in rows if row["policy"] == "commattn"} == {mine}
    assert {row["gap_to_central"] for row in rows} == {""}  # no central: no gap
    md = (tmp_path / "comm.md").read_text()
    assert "nearest-frontier - commattn (paired)" in md and "fine-tuned" not in md


def test_a_given_checkpoint_runs_on_every_map_size() -> None:
    """`repro comm` and the paired scripts pick a checkpoint per condition: the one the user
    gave wins everywhere (it is never swapped silently for the 40 x 40 fine-tuned one); without
    one, the fine-tuned one on its map size, else the shipped default."""
    from swarm.common.policy_spec import SHIPPED
    from swarm.studies.comm import checkpoint_for
    from world.config import WorldConfig, replace

    small, large = WorldConfig(), replace(WorldConfig(), height=40, width=40)
    assert checkpoint_for("commattn", large, "mine.pt") == "mine.pt"
    assert checkpoint_for("commattn", large, None) == str(SHIPPED / "scale/commattn_40x40_n20.pt")
    assert checkpoint_for("commattn", small, None) == str(SHIPPED / "commattn.pt")
    assert checkpoint_for("central", large, None) is None


@pytest.mark.procs
def test_paired_condition_script_writes_each_row_and_checks_its_arguments(tmp_path: Path) -> None:
    """The results scripts' command line (`swarm.studies.comm.paired_script`): bad arguments
    are one line; each condition's row is printed and OUT.json rewritten as it finishes; a spec
    without a checkpoint runs the one `repro comm` would (40 x 40: the fine-tuned CommAttn)."""
    script = tmp_path / "pair.py"
    script.write_text("import sys\nfrom swarm.studies.comm import paired_script\n"
                      "paired_script(sys.argv[1:], 'pair.py', {'nearest-frontier': "
                      "('nearest-frontier', None), 'commattn': ('commattn', None)}, 0, 100)\n")
    out = tmp_path / "out.json"

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, str(script), *args], cwd=ROOT, text=True,
                              capture_output=True, timeout=300)

    for bad in ((str(out), "99"), (str(out), "1", "--episodes", "x"), (str(out),)):
        r = run(*bad)
        assert r.returncode != 0 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = run(str(out), "1", "10", "--episodes", "2")
    assert r.returncode == 0, r.stderr
    rows = json.loads(out.read_text())["rows"]
    assert [row["condition"] for row in rows] == ["range 5", "40 x 40, 50 robots"]
    assert len(r.stdout.strip().splitlines()) == 2 and rows[0]["episodes"] == 2
    tuned = "checkpoints/scale/commattn_40x40_n20.pt"
    assert rows[1]["checkpoints"] == {"commattn": tuned}
    assert rows[0]["checkpoints"] == {"commattn": "checkpoints/commattn.pt"}
    mean, se = rows[0]["nearest_frontier_minus_commattn"]
    assert mean == pytest.approx(rows[0]["nearest-frontier"]["elratio"]
                                 - rows[0]["commattn"]["elratio"]) and se >= 0


@pytest.mark.procs
@pytest.mark.parametrize("flags,words", [
    (["fig9", "--comm-range", "3"], "--comm-range is not used by fig9 (fig9: it sweeps vision "
                                    "and comm range itself)"),
    (["fig9", "--vision", "7"], "--vision is not used by fig9"),
    (["table2", "--episodes", "5"], "--episodes is not used by table2; it is for fig4, fig5"),
    (["fig8", "--horizon", "20"], "--horizon is not used by fig8 (fig8: it draws training"),
    (["comm", "--policies", "random"], "it takes --comm-policies"),
    (["fig4", "--resume"], "--resume (or [repro] resume) goes on with an interrupted comm, "
                           "alone: `swarm repro comm --resume`, not fig4"),
    (["table1", "--robots", "2,4"], "--robots is not used by table1; it is for fig4"),
    (["fig9", "--policies", "random"],  # (UA pass: drew CommNet and CommAttn)
     "fig9 draws commnet and commattn only, not --policies random: name either"),
    (["fig9", "--policies", "commattn,random"], "only, not --policies random:")])
def test_repro_refuses_a_flag_its_item_does_not_use(tmp_path: Path, flags: list[str],
                                                     words: str,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """`repro fig9 --comm-range 3` made the same figure (and its Made-by line recorded the
    flag); `repro fig9 --vision 7` failed on commnet.pt though fig9 sweeps the vision."""
    r = swarm_here("repro", *flags, "--out", str(tmp_path / "o"), capsys=capsys)
    assert r.returncode == 2 and words in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


def test_fig9_takes_its_own_policies_and_leaves_all_without_them() -> None:
    from swarm.studies.fig9 import fig9_items
    from swarm.studies.repro import ALL_POLICIES

    assert fig9_items(["fig9"], ["commnet"], False) == ["fig9"]
    assert fig9_items(["fig9"], list(ALL_POLICIES), True) == ["fig9"]
    assert fig9_items(["table1", "fig9"], ["random"], False) == ["table1"]  # (`repro all`)
    with pytest.raises(ConfigError, match="not --policies random,vain"):
        fig9_items(["fig9"], ["commattn", "random", "vain"], False)


def test_the_comm_figure_names_the_policies_it_compares() -> None:
    from swarm.studies.comm import comm_title

    assert comm_title(["commattn", "nearest-frontier"]) == \
        "Where communication matters: commattn, nearest-frontier"
    assert comm_title(["commattn", "central"]).endswith("(central: a perfect radio)")


def test_table2_describes_only_the_planners_in_it() -> None:
    from swarm.studies.repro import ReproConfig, table2_notes

    def row(p: str, dec: bool = True, gap: float | None = None) -> dict:
        return {"policy": p, "decentralized": dec, "gap_closed": gap, "episodes": 7}

    cfg = ReproConfig(oracle_episodes=7)  # (the oracle's row: 7 episodes)
    text = table2_notes([row("commattn"), row("chain-plan"), row("central", False)], cfg)
    assert "`chain-plan` is a hand-written" in text and "team-beam" not in text
    assert "Rows marked * are not decentralized: `central` pools" in text
    assert "oracle" not in text and "gap" not in text
    text = table2_notes([row("random", gap=0.0), row("oracle", False, 1.0)], cfg)
    assert "first 7 episodes only" in text and "'gap'" in text and "chain-plan" not in text


@pytest.mark.procs
def test_repro_fig11_runs_on_the_configs_world(tmp_path: Path) -> None:
    """Figs. 10 and 11 are studied on `--config`'s map and team (static), as the other items:
    they ran on the default 20 x 20 map with 10 robots whatever the config said."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[world]\nheight = 10\nwidth = 10\nn_robots = 3\n[repro]\nfig11_episodes = 2\n")
    r = swarm("repro", "fig11", "--out", str(tmp_path), "--config", str(cfg), "--seed", "1")
    assert r.returncode == 0, r.stderr[-2000:]
    md = (tmp_path / "fig11_by_neighbours.md").read_text()
    assert "3 robots" in md and "10 robots" not in md, md[:400]
    assert md.startswith(f"# Fig. 11: mean communication-vector norm per cell (seed 1)\n\n"
                         f"Made by `swarm repro fig11 --out {tmp_path} --config {cfg} "
                         "--seed 1` (seed 1, "), md[:400]  # as every other item
    assert "Checkpoints: commattn `checkpoints/commattn.pt`." in md, md[:600]  # (UA 75)


def on_terminal(columns: int, *args: str) -> str:
    """`swarm ARGS`'s stdout on a pseudo-terminal `columns` wide (ANSI codes removed)."""
    import fcntl
    import os
    import pty
    import struct
    import termios

    main_fd, sub_fd = pty.openpty()
    fcntl.ioctl(sub_fd, termios.TIOCSWINSZ, struct.pack("HHHH", 40, columns, 0, 0))
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", *args], cwd=ROOT, env=env,
                            stdin=subprocess.DEVNULL, stdout=sub_fd, stderr=subprocess.PIPE)
    os.close(sub_fd)
    out = b""
    while True:
        try:
            chunk = os.read(main_fd, 65536)
        except OSError:  # (EIO: the process closed its end)
            break
        if not chunk:
            break
        out += chunk
    os.close(main_fd)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err.decode()[-2000:]
    return re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", out.decode()).replace("\r", "")


@pytest.mark.procs
@pytest.mark.parametrize("columns", [75, 60, 50])
def test_swarm_eval_results_stay_whole_on_a_narrow_terminal(columns: int) -> None:
    """Below ~75 columns the results table cut its figures (`0.…`, `-17…`); it now turns the
    policies into columns, then stacks one block per policy: every figure whole to 50 columns."""
    res = on_terminal(columns, "eval", "--policy", "coordinated-frontier,nearest-frontier",
                      "--episodes", "3", "--robots", "4")
    assert "…" not in res and max(len(line.rstrip()) for line in res.splitlines()) <= columns
    assert "coordinated-frontier" in res and "nearest-frontier" in res
    figures = re.findall(r"-?\d+\.\d+%?(?:±\d+\.\d+)?", res)
    assert len(figures) >= 13, res  # six figures a policy, and the paired Δ
    assert re.search(r"-?\d\.\d{4}±\d\.\d{4}", res), res
    assert "reward: the episode's return per robot" in " ".join(res.split()), res  # (its unit)


@pytest.mark.procs
def test_swarm_runs_summary_line_counts_copies_to_others_of_both_kinds(tmp_path: Path) -> None:
    """The line under `swarm run`'s table said `messages delivered` = trajectory copies with
    each robot's own (never lost) beside `lost` of both kinds: a loss rate from the two was
    wrong. Both figures now count copies to other robots, of both kinds (UA pass 43)."""
    out = tmp_path / "r.json"
    res = on_terminal(120, "run", "--robots", "3", "--episodes", "1", "--policy", "commattn",
                      "--loss", "0.3", "--json", str(out))
    m = json.loads(out.read_text())["messages"]
    found = re.search(r"copies delivered (\d+) lost (\d+)", res)
    assert found, res[-2000:]
    assert int(found[1]) == m["traj_to_others"] + m["hidden_delivered"] and m["hidden_delivered"]
    assert int(found[2]) == m["lost"] > 0


@pytest.mark.procs
def test_eval_json_to_a_descriptor_link_prints_it(tmp_path: Path) -> None:
    """`--json /dev/stdout` prints the JSON after the table (a link of our own to the command's
    stdout: as root, the unfixed writer replaced the link, i.e. /dev/stdout, with a file)."""
    link = tmp_path / "stdout"
    link.symlink_to("/proc/self/fd/1")
    r = swarm("eval", "--policy", "random", "--robots", "4", "--episodes", "2", "--static",
              "--json", str(link))
    assert r.returncode == 0, r.stderr
    assert link.is_symlink()
    table, _, obj = r.stdout.partition("\n{")
    assert "elratio" in table
    assert json.JSONDecoder().raw_decode("{" + obj)[0]["policy"] == "random"


def test_bench_swarm_refuses_typos_in_its_lists_and_empty_hosts(
        capsys: pytest.CaptureFixture[str]) -> None:
    """UA pass 61: `--robots 10,,25` ran as 10,25, `--robots 2,2 --policy random,random` four
    identical runs, and `--hosts 5 --robots 2` three empty hosts (`--hosts 100`: a hundred
    namespaces, no output for minutes) where `swarm run` refuses. Each is now one line, exit 2,
    before anything starts."""
    from swarm.cli import main

    for flags, why in ((["--robots", "10,,25"], "--robots expects comma-separated integers, "
                                                "got '10,,25'"),
                       (["--robots", "2,2"], "--robots expects distinct integers, got '2,2'"),
                       (["--robots", "2", "--policy", "random,random"],
                        "--policy expects distinct comma-separated names, got 'random,random'"),
                       (["--robots", "2", "--policy", "random,"], "names, got 'random,'"),
                       (["--robots", "2,3", "--hosts", "3"], "bench swarm hosts 3 is more hosts "
                                                             "than the 2 robots")):
        assert main(["bench", "swarm", "--episodes", "1", *flags]) == 2, flags
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and why in err, (flags, err)
    assert main(["run", "--headless", "--episodes", "1", "--robots", "2", "--hosts", "5"]) == 2
    assert capsys.readouterr().err == ("swarm: error: --hosts 5 is more hosts than the 2 robots "
                                       "(robots are dealt round robin: a host without one would "
                                       "be empty)\n")


def test_an_output_over_an_input_or_another_output_is_refused_before_anything_runs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """UA pass: `--json` naming the command's own checkpoint, recording or other output replaced
    it (`swarm run --record same.mcap --json same.mcap` exited 0 with the result JSON in the
    recording). Refused in one line, exit 2, before any process or folder is made; the input
    is left as it was."""
    from swarm.cli import main

    ckpt, logs = tmp_path / "ck.pt", tmp_path / "logs"
    ckpt.write_bytes((ROOT / "checkpoints" / "commattn.pt").read_bytes())
    before = ckpt.read_bytes()
    run = ["run", "--headless", "--robots", "3", "--episodes", "1", "--log-dir", str(logs)]
    cases = (
        ([*run, "--record", str(tmp_path / "same.mcap"), "--json", str(tmp_path / "same.mcap")],
         f"--json and --record are the same file ({tmp_path / 'same.mcap'})"),
        ([*run, "--policy", "commattn", "--checkpoint", str(ckpt), "--json",
          f"{tmp_path}/../{tmp_path.name}/ck.pt"], "is also --checkpoint, which this command "
                                                   "reads: it would be overwritten"),
        (["eval", "--episodes", "2", "--json", str(tmp_path / "e.csv"), "--episodes-csv",
          str(tmp_path / "e.csv")], "--json and --episodes-csv are the same file"),
        (["eval", "--episodes", "2", "--policy", "commattn", "--checkpoint", f"commattn={ckpt}",
          "--episodes-csv", str(ckpt)], f"--episodes-csv {ckpt} is also --checkpoint"),
        (["learner", "--run-id", "r1", "--out", str(logs), "--json", str(logs / "curve.csv")],
         "--json and --out's curve.csv are the same file"))
    # the files a config file names count as their flags do, and a flag overrides its key
    both = tmp_path / "both.toml"
    both.write_text(f'[eval]\njson = "{tmp_path}/e.csv"\nepisodes_csv = "{tmp_path}/e.csv"\n'
                    f'checkpoints = {{ commattn = "{ckpt}" }}\n')
    cases += ((["eval", "--config", str(both), "--episodes", "2"],
               "[eval] json and [eval] episodes_csv are the same file"),
              (["eval", "--config", str(both), "--episodes-csv", str(ckpt)],
               f"--episodes-csv {ckpt} is also [eval] checkpoints"),
              (["eval", "--config", str(both), "--episodes-csv", str(tmp_path / "f.csv"),
                "--json", str(both)], "--json"))
    for argv, why in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and why in err, (argv, err)
    assert ckpt.read_bytes() == before and not logs.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["both.toml", "ck.pt"]
    # a device is written in place, never replaced: two outputs may share /dev/null
    assert main(["eval", "--episodes", "1", "--batch", "1", "--policy", "random", "--json",
                 "/dev/null", "--episodes-csv", "/dev/null"]) == 0


def test_eval_pairs_two_checkpoints_of_one_policy_under_a_label(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """UA pass 76: your CommAttn against the shipped one could not run in one `swarm eval` (a
    policy runs once): `LABEL=NAME` runs NAME again under a label, with its own checkpoint,
    paired over the same episodes."""
    other = str(ROOT / "checkpoints" / "commattn_nomemory.pt")
    out, rows = tmp_path / "e.json", tmp_path / "e.csv"
    r = swarm_here("eval", "--policy", "commattn,mine=commattn", "--checkpoint",
                   f"mine={other}", "--episodes", "3", "--robots", "3", "--horizon", "6",
                   "--json", str(out), "--episodes-csv", str(rows), capsys=capsys)
    assert r.returncode == 0, r.stderr
    first, mine = json.loads(out.read_text())["results"]
    assert (first["policy"], first["checkpoint"], "runs" in first) == (
        "commattn", "checkpoints/commattn.pt", False)
    assert (mine["policy"], mine["runs"], mine["checkpoint"]) == (
        "mine", "commattn", "checkpoints/commattn_nomemory.pt")
    assert mine["elratio_paired"]["vs"] == "commattn" and mine["elratio_mean"] != \
        first["elratio_mean"]  # (another network on the same episodes)
    assert {row["policy"] for row in csv.DictReader(rows.open())} == {"commattn", "mine"}
    for policy, says in (("commattn,commnet=commattn", "that is no policy's name"),
                         ("mine=commattn,mine=commnet", "'mine' is named twice"),
                         ("mine=all", "a label names one policy, not all"),
                         ("mine=nope", "unknown policy 'nope'")):
        r = swarm_here("eval", "--policy", policy, "--episodes", "1", capsys=capsys)
        assert r.returncode == 2 and says in r.stderr and r.stderr.count("\n") == 1, r.stderr
    r = swarm_here("eval", "--policy", "commattn", "--checkpoint", f"mine={other}",
                   "--episodes", "1", capsys=capsys)  # (a label not run: as any stray name)
    assert r.returncode == 2 and "'mine' is not a policy" in r.stderr, r.stderr
