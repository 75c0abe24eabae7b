"""Claiming a run id: one live `swarm run` per id on a machine, decided atomically."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT, swarm

# a real `swarm` process whose modules are loaded and which waits for a line on stdin before
# main(): two of them released together start their commands in the same instant
GATED = "import sys; from swarm.cli import main; sys.stdin.readline(); sys.exit(main(sys.argv[1:]))"


def gated(*args: str, env: dict[str, str]) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-c", GATED, *args], cwd=ROOT, text=True, env=env,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


@pytest.mark.procs
def test_two_runs_of_one_id_started_in_the_same_instant_one_is_refused(tmp_path: Path) -> None:
    """The id was checked against the run registry, which the run wrote only once its
    supervisor started: two runs started together both passed the check and both ran. Now
    the supervisor takes the id before it starts anything (an exclusive lock, held for the
    run's life): exactly one runs."""
    env = {**os.environ, "TMPDIR": str(tmp_path)}  # (the registry and its locks: ours alone)
    run = ("run", "--headless", "--robots", "2", "--policy", "commattn", "--episodes",
           "2", "--seed", "3", "--run-id", "sameinstant")
    procs = [gated(*run, env=env) for _ in range(2)]
    try:
        for p in procs:
            assert p.stdin is not None
            p.stdin.write("go\n")
            p.stdin.flush()
        outs = [p.communicate(timeout=180) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
                p.communicate(timeout=60)
    codes = sorted(p.returncode for p in procs)
    assert codes == [0, 2], (codes, [err for _, err in outs])
    refused = next(err for p, (_, err) in zip(procs, outs, strict=True) if p.returncode == 2)
    assert refused == "swarm: error: run id 'sameinstant' is taken by a swarm running on this " \
        "machine; give another --run-id\n", refused
    assert not list((tmp_path / "swarm-runs").glob("*")), "the claim outlived its run"


@pytest.mark.procs
def test_a_claimed_id_is_refused_and_freed_when_its_holder_dies(tmp_path: Path) -> None:
    """A live holder of the id (before its run registered, or any time after) refuses it; one
    SIGKILLed (no chance to let go) leaves nothing in the way: the kernel dropped its lock."""
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    holder = subprocess.Popen(
        [sys.executable, "-c", "from swarm.common.spawn import claim_run; claim_run('held'); "
         "print('held', flush=True); input()"], cwd=ROOT, env=env, text=True,
        stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        run = ("run", "--headless", "--robots", "2", "--policy", "nearest-frontier",
               "--episodes", "1", "--run-id", "held")
        r = swarm(*run, env={"TMPDIR": str(tmp_path)})
        assert r.returncode == 2 and "run id 'held' is taken" in r.stderr, r.stderr
        assert [p.name for p in tmp_path.iterdir()] == ["swarm-runs"]  # nothing else made
    finally:
        holder.kill()
        holder.wait()
    r = swarm(*run, env={"TMPDIR": str(tmp_path)})
    assert r.returncode == 0, r.stderr


def test_one_process_cannot_hold_a_run_id_twice(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                                 ) -> None:
    """Two supervisors of one id in one process (a sweep's, a test's) are refused as two
    processes are; a released id is free again, and nothing of its claim is left."""
    from swarm.common.spawn import check_run_free, claim_run, release_run
    from world.config import ConfigError

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr("tempfile.tempdir", None)  # (gettempdir reads TMPDIR again)
    claim_run("twice")
    try:
        with pytest.raises(ConfigError, match="run id 'twice' is taken"):
            claim_run("twice")
        with pytest.raises(ConfigError, match="is taken"):
            check_run_free("twice")
    finally:
        release_run("twice")
    check_run_free("twice")
    assert not list((tmp_path / "swarm-runs").iterdir())


def dead_pid() -> int:
    """The pid of a process that has exited (and been reaped)."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


@pytest.mark.procs
def test_a_sigkilled_runs_entry_and_lock_are_both_removed_by_whoever_finds_it(
        tmp_path: Path) -> None:
    """A SIGKILLed supervisor leaves its registry entry and its id's lock file; `swarm fault
    --run ID` said the run was gone and removed the entry, but the lock file stayed forever."""
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    runs = tmp_path / "swarm-runs"
    sup = subprocess.Popen([sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots",
                            "2", "--size", "8x8", "--episodes", "50", "--run-id", "k1"],
                           cwd=ROOT, env=env, text=True, stdout=subprocess.PIPE,
                           stderr=subprocess.DEVNULL)
    try:
        assert sup.stdout is not None
        for line in sup.stdout:  # its first status: registered, robots running
            if line.startswith('{"status"'):
                break
        assert sorted(p.name for p in runs.iterdir()) == ["k1.json", "k1.lock"]
    finally:
        sup.kill()  # (its children follow: they die with their supervisor)
        sup.communicate()
    assert sorted(p.name for p in runs.iterdir()) == ["k1.json", "k1.lock"]  # left behind
    r = swarm("fault", "--run", "k1", "--loss", "0.1", env={"TMPDIR": str(tmp_path)})
    assert r.returncode == 2 and "swarm 'k1' is no longer running" in r.stderr, r.stderr
    assert not list(runs.iterdir())


def test_a_dead_runs_entry_leaves_a_live_holders_lock_alone(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The lock of an id a live process holds (a new run of it, still starting) is never removed
    with a dead run's entry: it is what refuses a second run of the id. Once nobody holds it, a
    claim of the id removes the dead run's entry with the lock."""
    from swarm.common.spawn import check_run_free, lookup_run, registry
    from world.config import ConfigError

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr("tempfile.tempdir", None)
    runs = tmp_path / "swarm-runs"
    holder = subprocess.Popen(
        [sys.executable, "-c", "from swarm.common.spawn import claim_run; claim_run('again'); "
         "print('held', flush=True); input()"], cwd=ROOT, text=True,
        env={**os.environ, "TMPDIR": str(tmp_path)}, stdin=subprocess.PIPE,
        stdout=subprocess.PIPE)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        registry("again").write_text(f'{{"hub": "tcp/127.0.0.1:9", "pid": {dead_pid()}}}')
        with pytest.raises(ConfigError, match="'again' is no longer running"):
            lookup_run("again")
        assert (runs / "again.lock").exists()
        with pytest.raises(ConfigError, match="run id 'again' is taken"):
            check_run_free("again")
    finally:
        holder.kill()
        holder.wait()
    registry("again").write_text(f'{{"hub": "tcp/127.0.0.1:9", "pid": {dead_pid()}}}')
    check_run_free("again")
    assert not list(runs.iterdir())
