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
