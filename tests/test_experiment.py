"""`swarm experiment FILE` as a user runs it: a bad file or flag is one line and exit 2 before
any process is spawned; `--episodes`/`--seeds` shrink a sweep, are recorded, and keep
`--resume` honest."""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from conftest import ROOT, swarm, swarm_here

from swarm.studies.experiment_plan import plan
from world.config import ConfigError

SHIPPED = sorted((ROOT / "deploy" / "experiments").glob("*.toml"))


def sweep_file(tmp_path: Path, experiment: str, head: str = "[world]\nn_robots = 2\n\n"
               "[run]\nepisodes = 3\n") -> str:
    """A small experiment file: `head` (world and run tables) and the `[experiment]` lines."""
    path = tmp_path / "sweep.toml"
    path.write_text(head + ("\n[experiment]\n" + experiment if experiment else ""))
    return str(path)


BASE = 'name = "t"\nparameter = "loss"\nvalues = [0.0]\nseeds = [0]\n'
BAD_FILES = {  # file's [experiment] lines (None: the file is empty) -> words of the error
    "unknown policy": (BASE + 'policies = ["nearest-frontier", "nosuch"]\n',
                       ["policy 'nosuch'", "unknown policy"]),
    "missing checkpoint": (BASE + 'policies = ["commattn"]\ncheckpoints = {commattn = '
                           '"/nope.pt"}\n', ["'commattn'", "/nope.pt"]),
    "checkpoint of a policy not swept": (BASE + 'policies = ["nearest-frontier"]\n'
                                         'checkpoints = {comattn = "checkpoints/commattn.pt"}\n',
                                         ["checkpoints", "comattn"]),
    "checkpoint of the wrong policy": (BASE + 'policies = ["commattn"]\ncheckpoints = '
                                       '{commattn = "checkpoints/vain.pt"}\n', ["'vain'"]),
    "partition beyond the team": ('name = "t"\nparameter = "partition"\nvalues = ["", "0-1/2-3"]'
                                  '\npolicies = ["random"]\nseeds = [0]\n',
                                  ["partition", "0-1/2-3", "robot"]),
    "no parameter": ('values = [0.0]\npolicies = ["random"]\n', ["[experiment]", "parameter"]),
    "seed not an integer": ('name = "t"\nparameter = "loss"\nvalues = [0.0]\n'
                            'policies = ["random"]\nseeds = ["a"]\n', ["seeds", "integers"]),
    "no [experiment] table": ("", ["no [experiment] table"]),
    "a world setting swept": ('name = "t"\nparameter = "comm_range"\nvalues = [2, 5]\n'
                              'policies = ["random"]\nseeds = [0]\n',
                              ["partition", "swarm repro comm"]),
    "a relative checkpoint path": (BASE + 'policies = ["commattn"]\ncheckpoints = {commattn = '
                                   '"mine.pt"}\n', ["mine.pt (relative to /"]),
}


@pytest.mark.parametrize("head, says", [
    ('[world]\ndynamic = "true"\n', '[world] dynamic must be true or false, got \'true\''),
    ("[world]\ndynamic = 0\n", "[world] dynamic must be true or false, got 0"),
])
def test_a_switch_in_a_sweep_or_config_file_must_be_a_boolean(tmp_path: Path, head: str,
                                                            says: str, capsys: Any) -> None:
    """`[world] dynamic = "true"` or `0` was read as a setting in a sweep and in every command's
    `--config` (and `[experiment] record = 1` in a sweep) while `[run]`, `[learner]` and
    `[train]` refused it."""
    from swarm.cli import main

    path = sweep_file(tmp_path, BASE + 'policies = ["random"]\n', head=head)
    with pytest.raises(ConfigError) as err:
        plan(path)
    assert says in str(err.value)
    conf = tmp_path / "c.toml"
    conf.write_text(head)
    assert main(["eval", "--policy", "random", "--episodes", "1", "--config", str(conf)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], lines
    with pytest.raises(ConfigError, match=r"\[experiment\] record must be true or false, got 1"):
        plan(sweep_file(tmp_path, BASE + 'policies = ["random"]\nrecord = 1\n'))


@pytest.mark.procs
@pytest.mark.parametrize("case", list(BAD_FILES))
def test_a_bad_sweep_is_one_line_and_exit_2_before_any_run(
        tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]) -> None:
    """What would fail in a robot process, or run a sweep nobody asked for, is refused first."""
    lines, words = BAD_FILES[case]
    out = tmp_path / "out"
    r = swarm_here("experiment", sweep_file(tmp_path, lines), "--out", str(out), capsys=capsys)
    assert r.returncode == 2, (r.returncode, r.stderr[-500:])
    assert r.stderr.startswith("swarm: error: ") and len(r.stderr.strip().splitlines()) == 1
    assert all(w in r.stderr for w in words), r.stderr
    assert "logs in" not in r.stderr and not out.exists()  # nothing ran, nothing was written


def test_a_sweep_that_would_train_is_refused_before_any_run(tmp_path: Path) -> None:
    """`[run] train = true` in a sweep: its world waited a minute for a learner no sweep starts,
    then the sweep failed ("no learner came alive within 60 s")."""
    path = sweep_file(tmp_path, BASE + 'policies = ["commattn"]\n',
                      head="[run]\ntrain = true\nepisodes = 1\n")
    with pytest.raises(ConfigError, match=r"\[run\] train: a sweep evaluates, it does not train"):
        plan(path)


@pytest.mark.procs
def test_an_empty_file_a_directory_or_no_file_is_one_line_and_exit_2(tmp_path: Path) -> None:
    empty = tmp_path / "empty.toml"
    empty.write_text("")
    cases = {str(empty): "no [experiment] table", str(tmp_path): "is a directory",
             str(tmp_path / "nope.toml"): "not found"}
    for path, words in cases.items():
        r = swarm("experiment", path, "--out", str(tmp_path / "out"), timeout=60)
        assert r.returncode == 2 and words in r.stderr, (path, r.returncode, r.stderr[-500:])
        assert len(r.stderr.strip().splitlines()) == 1 and path in r.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.procs
@pytest.mark.parametrize("flags, words", [
    (["--seeds", "a"], "--seeds must be integers"), (["--seeds", "0,,1"], "--seeds must be"),
    (["--seeds", "1,1"], "seeds repeat 1"), (["--seeds", "9999999999"], "seed must lie"),
    (["--episodes", "0"], "--episodes must be >= 1"),
    (["--episodes", "x"], "argument --episodes: invalid int value"),
    (["--episodes", "1", "--no-out"], "need --out DIR"),
    (["--empty-out"], "--out wants a directory, got an empty name"),  # (fell back to results/)
    (["--episodes", "1", "--empty-out"], "--out wants a directory, got an empty name")])
def test_bad_episodes_or_seeds_flags_are_one_line_and_exit_2(
        flags: list[str], words: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = [] if "--no-out" in flags else ["--out", "" if "--empty-out" in flags else
                                          "/nonexistent/x"]
    flags = [f for f in flags if f not in ("--no-out", "--empty-out")]
    r = swarm_here("experiment", "deploy/experiments/tiny.toml", *out, *flags, capsys=capsys)
    assert r.returncode == 2 and words in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_every_shipped_sweep_plans_and_shrinks_to_a_quick_try(path: Path) -> None:
    """Each shipped file passes the checks, and `--episodes 1 --seeds 0` leaves one run per
    (policy, value) of one episode."""
    try:
        full = plan(str(path))
        quick = plan(str(path), episodes=1, seeds=(0,))
    except ConfigError as exc:
        if "--netns needs" in str(exc):  # (not root, or no iptables: .ci/run installs it)
            pytest.skip(str(exc))
        raise
    assert len(full.points) == len(full.exp.policies) * len(full.exp.values) * len(full.exp.seeds)
    assert len(quick.points) == len(quick.exp.policies) * len(quick.exp.values)
    assert {(p.run.episodes, p.run.seed) for p in quick.points} == {(1, 0)}
    assert quick.overrides == ("--episodes", "1", "--seeds", "0")


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.procs
def test_episodes_and_seeds_flags_override_the_file_and_keep_resume_honest(
        tmp_path: Path) -> None:
    """A quick try of a 3-seed, 3-episode file; the CSV and the Markdown record what ran, and
    `--resume` refuses a CSV made with other episodes or seeds but extends one with more seeds."""
    src = sweep_file(tmp_path, 'name = "quick"\nparameter = "loss"\nvalues = [0.0]\n'
                     'policies = ["nearest-frontier"]\nseeds = [0, 1, 2]\n')
    out = tmp_path / "out"
    r = swarm("experiment", src, "--out", str(out), "--episodes", "1", "--seeds", "4",
              timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = _rows(out / "quick.csv")
    assert [(r_["seed"], r_["episodes"], r_["twin"]) for r_ in rows] == [("4", "1", "identical")]
    md = (out / "quick.md").read_text()
    assert f"swarm experiment {src} --out {out} --episodes 1 --seeds 4" in md  # rerun: same place
    assert "seeds 4; 1 episode per run" in md
    assert "World: 2 robots, 20 x 20" in md and "sd over seeds" in md
    rec = json.loads((out / "quick.json").read_text())  # everything that made the sweep
    assert rec["experiment_file"] == Path(src).read_text() and rec["run"]["episodes"] == 1
    assert rec["world"]["n_robots"] == 2 and rec["checkpoints"] == {"nearest-frontier": None}
    assert rec["experiment"]["seeds"] == [4] and rec["provenance"]["versions"]
    before = (out / "quick.csv").read_text()
    for flags, words in ((["--seeds", "4"], "runs of 1 episode(s) each, this sweep's runs have 3"),
                         (["--episodes", "1", "--seeds", "5"], "seed(s) 4, not in")):
        r = swarm("experiment", src, "--out", str(out), "--resume", *flags, timeout=60)
        assert r.returncode == 2 and words in r.stderr, r.stderr[-500:]
        assert (out / "quick.csv").read_text() == before
    r = swarm("experiment", src, "--out", str(out), "--resume", "--episodes", "1",
              "--seeds", "4,5", timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    after = _rows(out / "quick.csv")
    assert after[0] == rows[0] and [(a["seed"], a["episodes"]) for a in after] == [
        ("4", "1"), ("5", "1")]


def test_an_experiment_world_of_another_size_gets_the_blocks_of_its_size(tmp_path: Path) -> None:
    """`[world] height = 8, width = 8` in an experiment file means what it means to `swarm eval
    --config`: blocks at the paper's density (it kept 81 + 70 blocks and failed to fit)."""
    from world.config import WorldConfig, scaled_blocks

    text = (ROOT / "deploy" / "experiments" / "loss.toml").read_text()
    f = tmp_path / "small.toml"
    f.write_text(text.replace("[world]\nn_robots = 10", "[world]\nn_robots = 3\nheight = 8\n"
                              "width = 8"))
    world = plan(str(f)).world
    assert (world.height, world.width, world.n_robots) == (8, 8, 3)
    assert {"n_static": world.n_static, "n_dynamic": world.n_dynamic} == scaled_blocks(8, 8)
    assert world.n_static < WorldConfig.n_static


def test_a_run_with_process_faults_has_no_batched_twin() -> None:
    """The `twin` column said `differs: episode 0 tick 5 robot 1` for a crash the plan asked
    for: the batched evaluator has no processes to stop, so there is no twin to compare."""
    from swarm.procs.runconfig import RunConfig
    from swarm.studies.experiment import twin
    from world.config import WorldConfig

    world, rc = WorldConfig(n_robots=3), RunConfig(policy="nearest-frontier", episodes=1)
    assert twin(world, rc, {"crash": ["1@5"]}, {"actions": []}) == "n/a"
    assert twin(world, rc, {}, {"actions": [], "robots_lost": 1}) == "n/a"
    assert twin(world, rc, {}, {"actions": []}).startswith("differs: shapes")


@pytest.mark.procs
def test_a_sweep_with_process_faults_leaves_nothing_in_the_temp_dir(tmp_path: Path) -> None:
    """A run with a planned crash keeps its logs (`tidy_logs`: crashes are trouble); in a sweep
    nothing named that temp folder, and one was left in /tmp per run. Now it is moved beside
    the sweep's CSV and named on the run's line."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    head = "[world]\nn_robots = 3\n\n[run]\nepisodes = 1\n\n[faults]\ncrash = [\"1@5\"]\n"
    out = tmp_path / "out"
    r = swarm("experiment", sweep_file(tmp_path, BASE + 'policies = ["nearest-frontier"]\n',
                                       head), "--out", str(out), env={"TMPDIR": str(tmp)})
    assert r.returncode == 0, r.stderr[-2000:]
    assert [p.name for p in tmp.iterdir() if p.name != "swarm-runs"] == []
    assert not list((tmp / "swarm-runs").glob("*"))
    kept = out / "t-0-logs"
    assert f"logs in {kept}" in r.stderr, r.stderr
    assert (kept / "robot1.log").is_file() and (kept / "spec.json").is_file()


@pytest.mark.procs
def test_two_sweeps_of_one_file_at_once_do_not_take_each_others_run_ids(tmp_path: Path) -> None:
    """Run ids were `exp-NAME-K`, the same in every sweep of a file: a second sweep started
    while the first held `exp-t-0` aborted at that run ("give another --run-id", exit 2). Here
    a stand-in for that other sweep holds the id, as its supervisor does (swarm/common/spawn.py
    claim_run); this sweep's own ids carry its pid and are free."""
    import fcntl
    import os
    import subprocess
    import sys

    from swarm.studies.experiment_plan import point_run_id

    tmp = tmp_path / "tmp"
    (tmp / "swarm-runs").mkdir(parents=True)
    fd = os.open(tmp / "swarm-runs" / "exp-t-0.lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        out = tmp_path / "out"
        r = swarm("experiment", sweep_file(tmp_path, BASE + 'policies = ["nearest-frontier"]\n',
                                           "[world]\nn_robots = 2\n\n[run]\nepisodes = 1\n"),
                  "--out", str(out), env={"TMPDIR": str(tmp)})
    finally:
        os.close(fd)
    assert r.returncode == 0, r.stderr[-2000:]
    assert [row["twin"] for row in _rows(out / "t.csv")] == ["identical"]
    other = subprocess.run([sys.executable, "-c", "from swarm.studies.experiment_plan import "
                            "point_run_id; print(point_run_id('t', 0))"], check=True, text=True,
                           capture_output=True, cwd=ROOT).stdout.strip()
    assert other != point_run_id("t", 0) and other.startswith("exp-t-")
    long = point_run_id("n" * 64, 12345)  # a name of the most characters still fits the id
    assert len(long) <= 64 and long.endswith(f"-{os.getpid()}-12345")


@pytest.mark.procs
def test_resume_refuses_a_csv_of_another_world_faults_or_run_and_extends_values(
        tmp_path: Path) -> None:
    """`--resume` kept a sweep's rows after its world, base faults or tick changed, and the
    Markdown relabelled them with the new settings. Now the sweep record beside the CSV must
    match, field by field; more values (new rows) may be added."""
    head = ('[world]\nn_robots = 2\n\n[run]\nepisodes = 1\ntick_timeout = 0.5\n\n'
            '[faults]\njitter = "50ms"\n')
    exp = ('name = "r"\nparameter = "latency"\nvalues = ["0ms"]\nseeds = [0]\n'
           'policies = ["nearest-frontier"]\n')
    src = sweep_file(tmp_path, exp, head)
    out = tmp_path / "out"
    r = swarm("experiment", src, "--out", str(out), timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    before = (out / "r.csv").read_text()
    md = (out / "r.md").read_text()  # the settings that change the figures, all named
    assert "Run: tick 0.5 s, delivery radio. Faults at every point besides the swept " \
        "latency: jitter 50ms." in md, md
    assert "| nearest-frontier | 0ms | " in md and " ± - |" in md  # one seed: no sd
    for old, new, words in (("n_robots = 2", "n_robots = 3", "world.n_robots is 2 there, 3"),
                            ('jitter = "50ms"', 'jitter = "0ms"',
                             "[faults] at 0ms: jitter is '50ms' there, '0ms' here"),
                            ("tick_timeout = 0.5", "tick_timeout = 1.0",
                             "[run] tick_timeout is 0.5 there, 1.0 here"),
                            ('values = ["0ms"]', 'values = ["5ms"]', "value 0ms, not in")):
        Path(src).write_text((head + "\n[experiment]\n" + exp).replace(old, new))
        r = swarm("experiment", src, "--out", str(out), "--resume", timeout=60)
        assert r.returncode == 2 and words in r.stderr, r.stderr[-500:]
        assert len(r.stderr.strip().splitlines()) == 1
        assert (out / "r.csv").read_text() == before
    Path(src).write_text(head + "\n[experiment]\n" + exp.replace('["0ms"]', '["0ms", "450ms"]'))
    r = swarm("experiment", src, "--out", str(out), "--resume", timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = _rows(out / "r.csv")
    assert [a["value"] for a in rows] == ["0ms", "450ms"]
    # `delivered`: copies that reached another robot (a robot's own message is no delivery);
    # past the 0.4 s deadline every copy is late and none is delivered
    assert int(rows[0]["delivered"]) > 0 and int(rows[1]["late"]) > 0
    assert rows[1]["delivered"] == "0" and rows[0]["late"] == "0"
    assert (out / "r.csv").read_text().startswith(before)


@pytest.mark.parametrize("head, exp, says", [
    ('[world]\nhorizon = 10\n[run]\nepisodes = 1\n[faults]\ncrash = ["1@500"]\n', BASE,
     r'\[faults\] crash "1@500" is beyond the run\'s last tick 9'),
    ('[run]\nepisodes = 1\n[faults]\ncrash = ["1@0"]\nrestart = ["1@0"]\n', BASE,
     "a robot restarted at tick 0 is one that never crashed"),
    ('[run]\nclock = "real"\nwatchdog = 5\n', BASE,
     r'\[run\] watchdog is a virtual-clock setting .*not with \[run\] clock = "real"'),
    ('[run]\nclock = "real"\n', 'name = "t"\nparameter = "compute"\nvalues = ["0ms", "5ms"]\n'
     'seeds = [0]\n', r"compute = '5ms': --compute-ms .* with \[run\] clock = \"real\""),
    ("[run]\nepisodes = 1\n", 'name = "t"\nparameter = "overflow"\nvalues = ["queue", '
     '"drop"]\nseeds = [0]\n', "overflow = 'queue': it says what a bandwidth cap does; the "
     "sweep has no cap"),
])
def test_a_sweep_is_checked_as_swarm_run_checks_each_of_its_runs(
        tmp_path: Path, head: str, exp: str, says: str) -> None:
    """Each was refused by `swarm run` and swept anyway: a crash after the last tick (never
    fired, its twin column n/a), a crash and restart at tick 0 (the world waited a minute),
    virtual-clock settings on the real clock, overflow swept with no cap (every point one run)."""
    with pytest.raises(ConfigError, match=says):
        plan(sweep_file(tmp_path, exp + 'policies = ["random"]\n', head=head))


def test_resume_refuses_a_csv_made_with_another_checkpoint(tmp_path: Path) -> None:
    """A policy's checkpoint is part of its rows: another file for it is refused (the rows
    are checked against a real plan of each file, no process run)."""
    from swarm.studies.experiment import write_record
    from swarm.studies.experiment_plan import check_resume

    exp = ('name = "c"\nparameter = "loss"\nvalues = [0.0]\nseeds = [0]\n'
           'policies = ["commattn", "nearest-frontier"]\n')
    made = plan(sweep_file(tmp_path, exp + 'checkpoints = {commattn = '
                           f'"{ROOT}/checkpoints/commattn_loss30.pt"}}\n'))
    write_record(made, tmp_path)
    rows = [{"policy": "commattn", "value": "0.0", "seed": "0", "episodes": "3"}]
    check_resume(rows, made, tmp_path / "c.csv")  # the same sweep: resumed
    other = plan(sweep_file(tmp_path, exp))  # commattn on the shipped checkpoint
    with pytest.raises(ConfigError, match="checkpoint of commattn is "
                       "'checkpoints/commattn_loss30.pt' there, 'checkpoints/commattn.pt' here"):
        check_resume(rows, other, tmp_path / "c.csv")
    (tmp_path / "c.json").unlink()
    with pytest.raises(ConfigError, match="no readable sweep record"):
        check_resume(rows, made, tmp_path / "c.csv")
    # the same path, other weights (retrained or replaced in place): its bytes differ
    mine = tmp_path / "mine.pt"
    shutil.copyfile(ROOT / "checkpoints/commattn_loss30.pt", mine)
    write_record(plan(sweep_file(tmp_path, exp + f'checkpoints = {{commattn = "{mine}"}}\n')),
                 tmp_path)
    shutil.copyfile(ROOT / "checkpoints/commattn.pt", mine)
    with pytest.raises(ConfigError, match="SHA-256 of the checkpoint of commattn is '"):
        check_resume(rows, plan(sweep_file(tmp_path, exp + f'checkpoints = {{commattn = '
                                           f'"{mine}"}}\n')), tmp_path / "c.csv")


def test_the_sd_over_seeds_is_the_sample_sd() -> None:
    """The Markdown's `± sd over seeds` divided by n; it is the sample sd (n - 1), as it says."""
    from swarm.studies.experiment import _stats

    rows = [{"policy": "p", "value": "0.1", "elratio_mean": x} for x in ("0.5", "0.7")]
    mean, sd = _stats(rows, "p", 0.1, "elratio_mean")
    assert mean == pytest.approx(0.6) and sd == pytest.approx(0.1 * 2 ** 0.5)


@pytest.mark.parametrize("key, value, place", [
    ("policy", '"random"', "[experiment] policies"),
    ("checkpoint", '"nonexistent.pt"', "[experiment] checkpoints"),
    ("seed", "3", "[experiment] seeds")])
def test_a_run_setting_each_point_sets_is_refused_and_not_recorded(
        tmp_path: Path, key: str, value: str, place: str) -> None:
    """`[run] policy = "random"` (or `checkpoint`, `seed`) was accepted, ignored (every run takes
    its own from `[experiment]`) and written into the sweep record, which also claimed
    `"policy": "commattn"` for a frontier-only sweep. The committed records, made before, still
    resume."""
    from swarm.studies.experiment import _read_rows, write_record
    from swarm.studies.experiment_plan import check_resume

    exp = BASE + 'policies = ["nearest-frontier"]\n'
    with pytest.raises(ConfigError, match=rf"\[run\] {key}: a sweep sets it per run from "
                       rf"{re.escape(place)}; remove it from \[run\]"):
        plan(sweep_file(tmp_path, exp, head=f"[run]\nepisodes = 1\n{key} = {value}\n"))
    write_record(plan(sweep_file(tmp_path, exp)), tmp_path)
    run = json.loads((tmp_path / "t.json").read_text())["run"]
    assert run["episodes"] == 3 and not {"policy", "checkpoint", "seed", "run_id"} & set(run)
    shipped = ROOT / "results" / "experiments" / "loss.csv"  # its record holds run.policy
    assert "policy" in json.loads(shipped.with_suffix(".json").read_text())["run"]
    check_resume(_read_rows(shipped), plan(str(ROOT / "deploy/experiments/loss.toml")), shipped)


@pytest.mark.procs
def test_a_sweep_killed_before_its_first_run_leaves_no_other_sweeps_rows_under_its_record(
        tmp_path: Path) -> None:
    """A 3-robot sweep started over a finished 2-robot one in the same folder wrote its record,
    then was stopped (Ctrl-C) before its first run ended: the 2-robot rows stayed in the CSV
    under the 3-robot record, and `--resume` published them as the 3-robot sweep's (no run,
    exit 0); its Markdown and PNG stayed too, and `--overwrite` left the old runs' recordings
    and kept logs. The old files now go before the new record is written (the summary files
    come at the end)."""
    import signal
    import subprocess
    import sys
    import time

    exp = BASE + 'policies = ["nearest-frontier"]\n'
    out = tmp_path / "out"
    r = swarm("experiment", sweep_file(tmp_path, exp, "[world]\nn_robots = 2\n\n[run]\n"
                                       "episodes = 1\n"), "--out", str(out), timeout=240)
    assert r.returncode == 0 and len(_rows(out / "t.csv")) == 1, r.stderr[-2000:]
    assert (out / "t.md").is_file() and (out / "t.png").is_file()
    bigger = sweep_file(tmp_path, exp, "[world]\nn_robots = 3\n\n[run]\nepisodes = 50\n")
    (out / "t-7.mcap").write_bytes(b"an old sweep's recording")  # (its 8th run's; -k: its own)
    (out / "t-3-logs").mkdir()
    (out / "t-note.mcap").write_bytes(b"not a run's")
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", "experiment", bigger,
                             "--out", str(out), "--overwrite"], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    record = out / "t.json"
    deadline = time.monotonic() + 120  # (a failsafe, not a measurement)
    while proc.poll() is None and time.monotonic() < deadline and \
            json.loads(record.read_text())["world"]["n_robots"] != 3:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)  # its first run (50 episodes) has not ended
    _, err = proc.communicate(timeout=60)
    assert json.loads(record.read_text())["world"]["n_robots"] == 3, err[-2000:]
    assert not (out / "t.csv").exists() or _rows(out / "t.csv") == [], err[-2000:]
    assert not (out / "t.md").exists() and not (out / "t.png").exists()  # (of the old rows)
    assert not (out / "t-7.mcap").exists() and not (out / "t-3-logs").exists()  # (its runs')
    assert (out / "t-note.mcap").exists()
    r = swarm("experiment", bigger, "--out", str(out), "--resume", "--episodes", "1",
              timeout=240)  # (none of its runs is in the CSV: it runs them)
    assert r.returncode == 0, r.stderr[-2000:]
    assert [row["twin"] for row in _rows(out / "t.csv")] == ["identical"]
    assert "World: 3 robots" in (out / "t.md").read_text()


@pytest.mark.procs
def test_a_folder_holding_the_sweeps_results_is_refused_without_resume_or_overwrite(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`swarm experiment loss.toml --out DIR --episodes 1 --seeds 0` on a folder holding the
    sweep silently replaced its 30 rows (stopped after 12 s: 2 rows, while loss.md and loss.png
    still described the 30). Now that folder is refused in one line, its files untouched."""
    import shutil

    out = tmp_path / "exp"
    out.mkdir()
    for f in (ROOT / "results" / "experiments").glob("loss.*"):
        shutil.copy(f, out)
    before = {f.name: f.read_bytes() for f in out.iterdir()}
    for flags, words in (
            (["--episodes", "1", "--seeds", "0"],
             f"{out} holds the results of sweep loss (30 runs in {out}/loss.csv): resume it "
             "(--resume), replace them (--overwrite) or choose another output folder"),
            (["--resume", "--overwrite"],
             "--resume adds to the sweep in the folder, --overwrite replaces it; give one")):
        r = swarm_here("experiment", "deploy/experiments/loss.toml", "--out", str(out), *flags,
                       capsys=capsys)
        assert r.returncode == 2 and r.stderr == f"swarm: error: {words}\n", r.stderr[-2000:]
    assert {f.name: f.read_bytes() for f in out.iterdir()} == before


def test_a_resumed_sweep_removes_the_temp_files_a_killed_one_left(tmp_path: Path) -> None:
    """A sweep SIGKILLed mid-write left `.t.csv.*.tmp` (and the like) in its folder, and
    `--resume` never removed them (`swarm train --resume` does). Every sweep now removes its
    own on start; another file's temp files stay (no process run: every point is done)."""
    from swarm.studies.experiment import _write_csv, run_experiment, write_record

    sweep = plan(sweep_file(tmp_path, BASE + 'policies = ["nearest-frontier"]\n'))
    out = tmp_path / "out"
    write_record(sweep, out)
    _write_csv(out / "t.csv", [{"policy": "nearest-frontier", "value": 0.0, "seed": 0,
                                "elratio_mean": 0.9, "episodes": 3}])
    stale = [out / f".t{ext}.k2j4x_9a.tmp" for ext in (".csv", ".md", ".png", ".json")]
    for f in stale:
        f.write_bytes(b"half a file")
    other = out / ".other.csv.abc.tmp"
    other.write_bytes(b"not the sweep's")
    res = run_experiment(sweep, out, resume=True)
    assert len(res["rows"]) == 1
    assert [f.name for f in stale if f.exists()] == [] and other.exists()


def _cmdline(pid: str) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:  # (it ended)
        return b""


@pytest.mark.procs
def test_a_sweep_whose_recorder_failed_says_so_and_exits_1(tmp_path: Path) -> None:
    """With `record = true`, a recorder killed mid-run left `t-0.mcap` cut short, and the sweep
    exited 0 with nothing in its CSV, Markdown or output saying so (`swarm run --record` exits
    1). Now the row is `recording_partial`, the Markdown names the file, a warning line says
    where the run's logs are, and the exit status is 1, the sweep's files still written. The
    recorder of run 0 is killed once that run's robots are spawned: the supervisor starts them
    only after the recorder is up, and they cannot end the run before the kill."""
    import os
    import signal
    import subprocess
    import sys
    import time

    src = sweep_file(tmp_path, 'name = "t"\nparameter = "loss"\nvalues = [0.0]\n'
                     'policies = ["nearest-frontier"]\nseeds = [0, 1]\nrecord = true\n',
                     "[world]\nn_robots = 3\nheight = 8\nwidth = 8\n\n[run]\nepisodes = 3\n")
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", "experiment", src, "--out",
                             str(out), "--overwrite"], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    run_id = f"exp-t-{proc.pid}-0".encode()  # (point_run_id in the sweep's process)
    try:
        deadline = time.monotonic() + 120  # (a failsafe, not a measurement)
        recorder = None
        while recorder is None and proc.poll() is None and time.monotonic() < deadline:
            lines = {p: _cmdline(p) for p in os.listdir("/proc") if p.isdigit()}
            if any(b"robot\0--id\0" in c and b"\0" + run_id + b"\0" in c
                   for c in lines.values()):
                recorder = next((int(p) for p, c in lines.items()
                                 if b"record\0--run-id\0" + run_id + b"\0" in c), None)
            time.sleep(0.02)
        assert recorder is not None, "no recorder of run 0 while its robots ran"
        os.kill(recorder, signal.SIGKILL)
        stdout, err = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, err[-2000:]
    rows = _rows(out / "t.csv")
    assert [(r["recording"], r["recording_partial"]) for r in rows] == [
        (str(out / "t-0.mcap"), "True"), (str(out / "t-1.mcap"), "False")]
    md = (out / "t.md").read_text()
    assert "Recordings cut short" in md and "`t-0.mcap` (logs in `t-0-logs/`)" in md
    assert "t-1.mcap" not in md
    assert f"wrote {out / 't.md'}" in stdout and (out / "t.png").is_file()
    said = [x for x in err.splitlines() if x.startswith("swarm: warning: the recording ")]
    assert said == [f"swarm: warning: the recording {out / 't-0.mcap'} is partial (its "
                    f"recorder failed); the run's logs are in {out / 't-0-logs'}"], err[-2000:]
    assert (out / "t-0-logs" / "recorder.log").is_file() and not (out / "t-1-logs").exists()
