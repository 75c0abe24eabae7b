"""The robots' fork server (`swarm.common.forkserver`): forked robots are the supervisor's own
children with their own command lines, a run forked equals the same run spawned, and the server
takes a bad request or a command line too long for it without going down."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT, swarm
from test_swarm import run_procs


def _cmdline(pid: int) -> list[bytes]:
    return Path(f"/proc/{pid}/cmdline").read_bytes().rstrip(b"\0").split(b"\0")


def _status(pid: int) -> dict[str, str]:
    return dict(line.split(":\t", 1) for line in
                Path(f"/proc/{pid}/status").read_text().splitlines() if ":\t" in line)


def _ppid(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


@pytest.mark.procs
def test_forked_robots_are_the_supervisors_children_with_their_command_lines(
        tmp_path: Path) -> None:
    """While a run plays: every robot's parent is the supervisor (adopted: it waits for them and
    signals them as for any child), its /proc command line is a spawned robot's, and the fork
    server is one thread that names the run; an interrupted run leaves none of them."""
    proc = subprocess.Popen(  # (SIGHUP ignored, as under nohup: a child's is so too)
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "3", "--policy",
         "nearest-frontier", "--episodes", "500", "--seed", "2", "--run-id", "forked1", "--json",
         str(tmp_path / "r.json")], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN))
    try:
        assert proc.stdout is not None
        next(line for line in proc.stdout if line.startswith('{"status"'))
        pids = run_procs("forked1")
        robots = {p: _cmdline(p) for p in pids if b"robot" in _cmdline(p)}
        servers = [p for p in pids if b"--fork-server" in _cmdline(p)]
        assert len(robots) == 3 and len(servers) == 1, {p: _cmdline(p) for p in pids}
        for pid, cmd in robots.items():
            assert _ppid(pid) == proc.pid
            assert cmd[:5] == [sys.executable.encode(), b"-m", b"swarm.cli", b"robot", b"--id"]
            assert cmd[cmd.index(b"--run-id") + 1] == b"forked1"
        assert {cmd[5] for cmd in robots.values()} == {b"0", b"1", b"2"}
        assert _ppid(servers[0]) == proc.pid
        assert len(os.listdir(f"/proc/{servers[0]}/task")) == 1  # (a fork copies one thread)
        ignored = {p: _status(p)["SigIgn"] for p in [proc.pid, *robots]}
        assert len(set(ignored.values())) == 1, ignored  # (the supervisor's, as if spawned)
        hup = min(robots)
        os.kill(hup, signal.SIGHUP)
        time.sleep(0.5)
        assert _status(hup)["State"][0] not in "ZX"  # (ignored: still in the run)
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-2000:]
    assert run_procs("forked1") == []


@pytest.mark.procs
def test_a_run_forked_equals_the_same_run_spawned(tmp_path: Path) -> None:
    """`SWARM_FORKSERVER=0`: every robot its own interpreter; the seeded run is the same, to
    its message counts."""
    res = {}
    for mode in ("1", "0"):
        out = tmp_path / f"r{mode}.json"
        r = swarm("run", "--headless", "--robots", "4", "--policy", "commattn", "--episodes",
                  "2", "--seed", "3", "--horizon", "12", "--json", str(out),
                  env={"SWARM_FORKSERVER": mode})
        assert r.returncode == 0, r.stderr[-2000:]
        res[mode] = json.loads(out.read_text())
    keys = ("elratio_mean", "reward_mean", "collisions_mean", "messages")
    assert {k: res["1"][k] for k in keys} == {k: res["0"][k] for k in keys}
    msgs = {m: {i: (s["msgs_in"], s["msgs_out"]) for i, s in r["robot_status"].items()}
            for m, r in res.items()}
    assert msgs["1"] == msgs["0"]


_SERVER_SCRIPT = """
import json, os, socket, sys
from pathlib import Path
from swarm.common import forkserver
from swarm.common.spawn import child_env
folder = Path(sys.argv[1])
fs = forkserver.start(child_env(), folder, "fsX", [])
socket.send_fds(fs.sock, [b"not json"], [0, 1, 2])
print("bad", fs.sock.recv(64).decode())
err = os.open(folder / "child.log", os.O_WRONLY | os.O_CREAT | os.O_APPEND)
kids = []
print("long", fs.spawn(["robot", "x" * forkserver.PAD], child_env(), err, kids), kids)
print("forked", fs.spawn(["robot", "--run-id", "fsX"], child_env(), err, kids), len(kids))
print("child", kids[0].wait(60), kids[0].pid != fs.proc.pid)
late = os.open(folder / "late.log", os.O_WRONLY | os.O_CREAT | os.O_APPEND)
go, said = os.pipe()
req = json.dumps({"args": ["robot", "--run-id", "fsX"], "env": child_env()}).encode()
socket.send_fds(fs.sock, [req], [late, late, late, go])
pid = int(fs.sock.recv(64))
os.close(go)
os.close(said)
print("given up", os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]))
fs.close()
print("server", fs.proc.wait(10))
"""


@pytest.mark.procs
def test_the_server_drops_a_bad_request_and_serves_on(tmp_path: Path) -> None:
    """A request that is not one is dropped (said in the server's log, answered 0); a command
    line longer than the server's pad is not forked (False: the supervisor spawns it); a child
    still forks after both, writes its stderr where it was told, and its exit status reaches
    the process that asked (its subreaper); a child whose go byte never comes (the asker gave
    up on it) exits without running the CLI; the server ends when its socket closes."""
    r = subprocess.run([sys.executable, "-c", _SERVER_SCRIPT, str(tmp_path)], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split("\n")[:6] == ["bad 0", "long False []", "forked True 1", "child 2 True",
                                        "given up 0", "server 0"], r.stdout
    assert "request dropped" in (tmp_path / "forkserver.log").read_text()
    assert (tmp_path / "late.log").read_text() == ""  # (it never ran the CLI)
    assert "the following arguments are required: --id" in (tmp_path / "child.log").read_text()
