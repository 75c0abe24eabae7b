"""Hostile input and process death: no message, signal or bad value takes a process down, hangs
it, or loses an episode uncounted (real processes, real Zenoh sessions on loopback)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zenoh
from conftest import ROOT, swarm, swarm_here

from swarm.common import forkserver
from swarm.common.spawn import registry
from swarm.net.keys import Keys
from swarm.net.learning import EpisodeRecord, RobotRollout, RolloutTick, Weights
from swarm.net.messages import (
    K_CONTROL,
    K_LSTATUS,
    K_RESULT,
    K_RSTATUS,
    K_STATUS,
    K_WEIGHTS,
    SCHEMA,
    Action,
    Bundle,
    Hidden,
    Obs,
    Traj,
    pack_record,
)
from swarm.net.zconfig import ZenohOptions
from world.core import METRIC_NAMES

TINY = """[world]
height = 10
width = 10
n_static = 12
n_dynamic = 8
n_robots = 3
horizon = 12
"""


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()[:300]
    except OSError:
        return f"{pid} (gone)"


def alive_pid(pid: int) -> bool:
    """A process that exists and is not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def run_pids(run_id: str) -> list[int]:
    """PIDs of live processes whose command line mentions the run id."""
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and int(d.name) != os.getpid():
            try:
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if run_id in cmd and "swarm.cli" in cmd and alive_pid(int(d.name)):
                pids.append(int(d.name))
    return pids


def start_run(tmp: Path, run_id: str, *args: str, toml: str = "") -> subprocess.Popen[bytes]:
    (tmp / "tiny.toml").write_text(TINY + toml)
    return subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--config", str(tmp / "tiny.toml"),
         "--run-id", run_id, "--json", str(tmp / "r.json"), "--log-dir", str(tmp / "logs"),
         *args], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def hub_of(run_id: str, proc: subprocess.Popen[bytes], timeout: float = 60) -> str:
    """The run's hub endpoint, once its world accepts connections."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            hub = json.loads(registry(run_id).read_text())["hub"]
            host, port = hub.split("/")[1].rsplit(":", 1)
            with socket.create_connection((host, int(port)), timeout=0.5):
                return hub
        except (OSError, ValueError, KeyError):
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            time.sleep(0.1)
    raise TimeoutError("the run never registered")


def hostile_payloads(keys: Keys) -> list[tuple[str, bytes]]:
    """Well-formed messages with out-of-range values in each field, on every key of a run, plus
    records of the right kind with the wrong contents."""
    v5 = bytes(25)
    bits = bytes(13)
    out: list[tuple[str, bytes]] = []
    for r in range(3):
        out += [(keys.obs(r), Obs(0, 1, r, 1, 1, v5, 0.0, False, 1e300).pack()),
                (keys.obs(r), Obs(0, 0, r, 1, 1, v5, 0.0, False, 100.0, version=-3).pack()),
                (keys.obs(r), Obs(0, 1, r, 99, 1, v5, 0.0, False, 100.0).pack()),
                (keys.obs(r), Obs(-1, 1, r, 1, 1, v5, float("nan"), False, 100.0).pack()),
                (keys.obs(r), Obs(0, 10**9, r, 1, 1, v5, 0.0, False, 100.0).pack()),
                (keys.inbox(r), Bundle(0, 1, r, [b"junk", b"\x93"]).pack()),
                (keys.inbox(r), Bundle(0, 1, 77, []).pack()),
                (keys.inbox(r), Bundle(0, 1, r, [], [r]).pack()),  # a successor below it
                (keys.inbox(r), Bundle(0, 1, r, [], "2").pack()),  # type: ignore[arg-type]
                (keys.inbox_hidden(r), Hidden(0, 1, 0, 42, bytes(256)).pack()),
                (keys.inbox_hidden(r), Hidden(0, 1, 0, 1, b"\xff\xff\xff\x7f" * 64).pack()),
                (keys.traj(r), Traj(0, 1, 99, 1, 1, bits, [], v5).pack()),
                (keys.traj(r), Traj(0, 1, r, -4, 1, bits, [], v5).pack()),
                (keys.traj(r), Traj(0, 1, r, 1, 1, b"", [10**12], v5).pack()),
                (keys.hidden(r), Hidden(0, 1, r, 9, b"\x00\x00\xc0\x7f" * 64).pack()),
                (keys.action(r), Action(0, 1, r, 9, 0.0).pack()),
                (keys.action(r), Action(0, 1, r, 3, 1e300).pack()),
                (keys.action(r), Action(0, 1, (r + 1) % 3, 3, 1.0).pack()),
                (keys.robot_status(r), pack_record(K_RSTATUS, {"robot": "x", "msgs_in": []})),
                (keys.rollout(r), RobotRollout(0, r, [RolloutTick(b"x", 2**62, True, 9, 5.0,
                                                                  0.0, -1)]).pack())]
    out += [(keys.control, pack_record(K_CONTROL, {"faults_table": {"partition": "0-999999999"}})),
            (keys.control, pack_record(K_CONTROL, {"faults_table": {"loss": [1], "robot": 5}})),
            (keys.control, pack_record(K_CONTROL, {"faults_table": {"latency": "1e9s"}})),
            (keys.control, pack_record(K_CONTROL, {"process": ["crash:99@1", "bogus"]})),
            (keys.status, pack_record(K_STATUS, {"pos": "x", "alive": 5, "ep": "y"})),
            (keys.learner_status, pack_record(K_LSTATUS, {  # the dashboard, a lockstep world
                "version": -1, "last_closed": "x", "pending": 2**63, "update_due": 3,
                "curve": "abc", "accounting": {"trained": "all"}})),
            (keys.learner_status, pack_record(K_LSTATUS, {"curve": [0.5, "x"]})),
            (keys.end, pack_record(K_RESULT, {"run_id": "another-run"})),
            (keys.end, b"\x00"),
            (keys.episode, EpisodeRecord(0, np.full((2, 3), np.inf, np.float32),
                                         np.ones((2, 3), bool), {"reward": 0.0}).pack()),
            (keys.worker_episodes(0), msgpack.packb([1, 12, 0, 0, 0, 1, {}, {}])),
            (keys.weights, Weights("commattn", 2**40, {}, {"x": np.full(3, np.nan, "<f4")})
             .pack()),
            (keys.weights, b"\x00" * 5000),
            # a shape whose numpy product wraps to 0, with an empty buffer (it killed robots)
            (keys.weights, msgpack.packb([SCHEMA, K_WEIGHTS, "commattn", 10**6, {},
                                          {"w": [[65536] * 4, b""]}])),
            # a status the supervisor would have fired process faults and drawn 500 robots on
            (keys.status, pack_record(K_STATUS, {
                "ep": 0, "t": 1, "run_tick": 2**62, "pos": [[999, -5]] * 500,
                "alive": [True] * 500, "elratio": 7.5, "block_coll": -3,
                "timeouts": list(range(1000))})),
            (keys.result, pack_record(K_RESULT, {"policy": "forged", "completed": 999,
                                                 "elratio_mean": 1.0, "success_rate": 1.0})),
            # episodes where no robot acted (the learner crashed on a batch of them)
            *((keys.episode, EpisodeRecord(ep, np.zeros((30, 3), np.float32),
                                           np.zeros((30, 3), bool),
                                           {k: 0.0 for k in METRIC_NAMES}).pack())
              for ep in (7, 8))]
    for r in range(3):  # kept for ever by a robot: bundles and hidden states of far ticks
        out += [(keys.inbox_hidden(r), Hidden(10**6, 1, 0, 1, bytes(256)).pack()),
                (keys.inbox_hidden(r), Hidden(0, 29, 0, 1, bytes(256)).pack()),
                (keys.inbox(r), Bundle(10**6, 1, r, []).pack())]
    return out


def test_an_inbox_flood_is_cut_at_its_bound_and_counted() -> None:
    """Past `max_events` queued events an inbox drops the newest and counts each (a real
    session delivering its own puts); what it kept comes out in order."""
    from swarm.net.inbox import Inbox

    with zenoh.open(ZenohOptions().to_config()) as s:
        inbox = Inbox(s, max_events=5).subscribe("flood/x", "x")
        pub = s.declare_publisher("flood/x")
        for k in range(20):
            pub.put(bytes([k]))
        deadline = time.monotonic() + 10
        while inbox.overflow + inbox.q.qsize() < 20 and time.monotonic() < deadline:
            time.sleep(0.01)
        kept = []
        while (ev := inbox.next(0.05)) is not None:
            kept.append(ev.payload)
        inbox.close()
    assert kept == [bytes([k]) for k in range(5)] and inbox.overflow == 15


def test_a_bundles_messages_are_checked_together_as_strictly_as_one_by_one() -> None:
    """`Traj.unpack_many` (a robot's bundle, checked column by column) accepts what per-message
    `unpack` accepts, refuses any bundle with one bad message, and names that message's fault."""
    from swarm.net.messages import BadMessage
    from world.config import WorldConfig

    cfg = WorldConfig(height=10, width=10, n_static=12, n_dynamic=8, n_robots=3, horizon=12)
    v5, bits = bytes(25), bytes(13)
    good = [Traj(0, 1, r, r, 2, bits, [3, 4, 99][:r + 1], v5).pack() for r in range(3)]
    assert Traj.unpack_many(good, cfg, 0, 1) == [Traj.unpack(p, cfg) for p in good]
    assert Traj.unpack_many([], cfg, 0, 1) == []
    bad = {"y=10": Traj(0, 1, 2, 10, 1, bits, [], v5), "x=-1": Traj(0, 1, 2, 1, -1, bits, [], v5),
           "recent cell=100": Traj(0, 1, 2, 1, 1, bits, [100], v5),
           "robot=3": Traj(0, 1, 3, 1, 1, bits, [], v5),
           "robot=True": Traj(0, 1, True, 1, 1, bits, [], v5),  # type: ignore[arg-type]
           "visited": Traj(0, 1, 2, 1, 1, bits[:-1], [], v5),
           "patch": Traj(0, 1, 2, 1, 1, bits, [], v5 + b"x"),
           "recent must be": Traj(0, 1, 2, 1, 1, bits, [1] * (cfg.recent_len + 1), v5),
           "robot 2 that does not fit": Traj(0, 2, 2, 1, 1, bits, [], v5),
           "robot 1 that does not fit": Traj(0, 1, 1, 1, 1, bits, [], v5)}
    for why, msg in bad.items():
        with pytest.raises(BadMessage, match=why):
            Traj.unpack_many(good[:2] + [msg.pack()], cfg, 0, 1)
    with pytest.raises(BadMessage, match="not msgpack|schema"):
        Traj.unpack_many(good[:2] + [b"\x93"], cfg, 0, 1)


def three_statuses(session: zenoh.Session, keys: Keys, timeout: float = 90) -> None:
    """Until a session has seen three of the world's statuses (the run is under way)."""
    ticks: list[bytes] = []
    sub = session.declare_subscriber(keys.status, lambda smp: ticks.append(b""))
    deadline = time.monotonic() + timeout
    while len(ticks) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    sub.undeclare()


@pytest.mark.procs
def test_a_lost_result_message_falls_back_to_the_worlds_result_file(tmp_path: Path) -> None:
    from swarm.common.atomic import write_json
    from swarm.common.spawn import child_result

    f = tmp_path / "world_result.json"
    assert child_result(f, "r1") is None  # the world died before writing it
    write_json(f, {"run_id": "r1", "completed": 3, "elratio_mean": 0.9})
    assert child_result(f, "r1") == {"run_id": "r1", "completed": 3, "elratio_mean": 0.9}
    assert child_result(f, "r2") is None  # another run's
    f.write_text("[1, 2")
    assert child_result(f, "r1") is None


def test_out_of_range_messages_on_every_key_are_dropped_and_counted(tmp_path: Path) -> None:
    """Every process stays alive and counts what it refused; the run completes."""
    run_id = "fuzz1"
    proc = start_run(tmp_path, run_id, "--policy", "commattn", "--train", "--train-batch", "2",
                     "--train-sync", "--episodes", "6", "--pace", "16", "--tick-timeout", "1")
    try:
        hub = hub_of(run_id, proc)
        keys = Keys(run_id)
        with zenoh.open(ZenohOptions(mode="client", connect=[hub]).to_config()) as session:
            three_statuses(session, keys)  # every robot is acting
            token = session.liveliness().declare_token(keys.alive_robot(8))  # no such robot
            for _ in range(3):
                for key, payload in hostile_payloads(keys):
                    session.put(key, payload)
                for key in (keys.action(0), keys.obs(0), keys.status):  # over 4 MB: dropped
                    # (blocking: a 5 MB put may be dropped by Zenoh itself on a loaded machine)
                    session.put(key, bytes(5 << 20),
                                congestion_control=zenoh.CongestionControl.BLOCK)
                time.sleep(0.5)
            token.undeclare()
            alive = run_pids(run_id)
            assert len(alive) >= 6, alive  # supervisor, world, learner, three robots
        assert proc.wait(timeout=180) == 0, proc.stderr.read().decode()[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["completed"] == 6 and res["robot_crashes"] == 0 and res["robots_lost"] == 0
    assert res["policy"] == "commattn" and sorted(res["robot_status"]) == ["0", "1", "2"]
    assert res["messages"]["oversized"] == 3  # (and the robot's and supervisor's, counted too)
    assert res["robot_status"]["0"]["oversized"] == 3, res["robot_status"]
    assert res["messages"]["bad"] > 0  # the world refused forged trajectories, actions, control
    assert res["messages"]["bad_by_key"].get(keys.learner_status, 0) > 0  # and learner statuses
    assert res["train_sync"]["timeouts"] == 0
    assert all(r["bad"] > 0 and r["errors"] == 0 for r in res["robot_status"].values())
    assert res["supervisor_bad"] > 0
    assert res["learner"]["bad"] > 0
    for log in (tmp_path / "logs").glob("*.log"):
        assert "Traceback" not in log.read_text(errors="replace"), log


@pytest.mark.procs
def test_foreign_garbage_in_a_recording_is_skipped_by_verify_not_a_divergence(
        tmp_path: Path) -> None:
    """A foreign peer's garbage on the run's keys (UA pass: on world/result it was reported as a
    divergence 'recorded unreadable, recomputed not msgpack'): every live process dropped it, so
    verification counts it as skipped and the recording verifies. So is a well-formed result the
    supervisor refused (UA pass 53: an empty one was 'a second world/result message'), and
    well-formed actions of a past tick (the replay took the last action of a tick, a stray put
    later over the real one) or of a future one (before the real one): the world takes only an
    action of the tick in play, the replay only the first after the robot's previous one."""
    run_id, f = "gx", tmp_path / "k.mcap"
    proc = start_run(tmp_path, run_id, "--policy", "nearest-frontier", "--episodes", "2",
                     "--pace", "10", "--record", str(f))
    try:
        hub = hub_of(run_id, proc)
        keys = Keys(run_id)
        with zenoh.open(ZenohOptions(mode="client", connect=[hub]).to_config()) as session:
            three_statuses(session, keys)  # mid-run
            for key in (keys.result, keys.status, keys.obs(1)):
                session.put(key, b"\xff\xfe")
            session.put(keys.result, msgpack.packb([1, K_RESULT, {}]))
            for ep, t, a in ((0, 0, 0), (0, 0, 8), (1, 6, 0), (1, 6, 8)):  # (one is not robot 1's)
                session.put(keys.action(1), Action(ep, t, 1, a, 1.0).pack())
        assert proc.wait(timeout=120) == 0, proc.stderr.read().decode()[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
    r = swarm("replay", str(f), "--verify", "--json", str(tmp_path / "v.json"))
    assert r.returncode == 0, r.stderr
    assert "4 unreadable messages skipped, as the live processes dropped them" in r.stdout, \
        r.stdout
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["ok"] and v["unreadable"] == 4 and v["checked"]["results"] == 1, v


@pytest.mark.procs
def test_a_hung_robot_rejoins_after_it_is_resumed(tmp_path: Path) -> None:
    """SIGSTOP past the lease, then SIGCONT (`--hang` / `--restart`): its session dropped, but the
    world did not end: the robot rejoins, acts again, and the stall and the rejoin are counted."""
    proc = start_run(tmp_path, "hang1", "--robots", "3", "--policy", "nearest-frontier",
                     "--episodes", "5", "--hang", "1@10", "--restart", "1@50", "--pace", "20")
    assert proc.wait(timeout=120) == 0, proc.stderr.read().decode()[-2000:]
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["completed"] == 5 and res["robots_lost"] == 0 and res["robot_restarts"] == 1
    st = res["robot_status"]["1"]
    assert st["stalls"] >= 1 and st["rejoins"] >= 1 and res["robot_stalls"] == st["stalls"]
    assert (np.array(res["actions"])[-1, :, 1] != 0).any()  # it acts in the last episode


@pytest.mark.procs
def test_a_hung_robot_holds_no_other_robot_back_in_virtual_time(tmp_path: Path) -> None:
    """Virtual clock, a watchdog as short as the lease: a robot hung before its trajectory held
    the others' bundles until the watchdog, and then they missed the tick too (all counted as
    timeouts, all frozen). Now the others get a watchdog of their own to decide."""
    r = swarm("run", "--headless", "--robots", "3", "--episodes", "1", "--policy",
              "nearest-frontier", "--hang", "1@5", "--restart", "1@12", "--watchdog", "1",
              "--run-id", "hangv", "--json", str(tmp_path / "r.json"), timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    missed = {i for line in r.stdout.splitlines() if '"status"' in line
              for i in json.loads(line)["status"]["timeouts"]}
    assert missed <= {1}, missed
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["completed"] == 1 and res["timeouts"] <= 2 and res["robot_restarts"] == 1


@pytest.mark.procs
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_the_supervisors_death_ends_every_process_of_its_run(
        tmp_path: Path, sig: int, capsys: pytest.CaptureFixture[str]) -> None:
    run_id = f"die{int(sig)}"
    proc = start_run(tmp_path, run_id, "--policy", "commattn", "--train", "--train-batch", "2",
                     "--episodes", "100000", "--pace", "10")
    try:
        hub_of(run_id, proc)
        deadline = time.monotonic() + 60
        def up() -> int:  # supervisor, world, 3 robots, learner (and a fork server, if one)
            return sum(_cmdline(p).split()[3:4] != [forkserver.SERVE] for p in run_pids(run_id))

        while up() < 6 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert up() >= 6
        proc.send_signal(sig)
        deadline = time.monotonic() + 10
        while run_pids(run_id) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = run_pids(run_id)
        assert left == [], [_cmdline(p) for p in left]  # which process outlived its parent
    finally:
        for pid in run_pids(run_id):
            os.kill(pid, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
    r = swarm_here("fault", "--run", run_id, "--loss", "0.1", capsys=capsys)  # registry gone/stale
    assert r.returncode == 2 and "swarm: error:" in r.stderr and "Traceback" not in r.stderr


CHILD = """
import sys, time
from swarm.common import spawn
spawn.SHUTDOWN_GRACE_S = 0.5
assert spawn.die_with_parent()
print("ready", flush=True)
try:
    time.sleep(60)
except KeyboardInterrupt:  # told to go: a cleanup that never ends (a put blocked on a dead peer)
    while True:
        time.sleep(0.05)
"""
PARENT = """
import subprocess, sys
from swarm.common.spawn import child_env
child = subprocess.Popen([sys.executable, "-c", sys.argv[1]], env=child_env())
print(child.pid, flush=True)
child.wait()
"""


def test_a_child_whose_cleanup_hangs_is_ended_after_its_grace() -> None:
    """The supervisor dies (SIGKILL); its child's unwinding never returns; the child is gone
    within SHUTDOWN_GRACE_S (0.5 s here) anyway, ended by SIGALRM."""
    parent = subprocess.Popen([sys.executable, "-c", PARENT, CHILD], cwd=ROOT,
                              stdout=subprocess.PIPE, text=True)
    child = 0
    try:
        assert parent.stdout is not None
        child = int(parent.stdout.readline())
        assert parent.stdout.readline().strip() == "ready"
        parent.kill()
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while alive_pid(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not alive_pid(child), "the child outlived its grace"
    finally:
        if child and alive_pid(child):
            os.kill(child, signal.SIGKILL)
        if parent.poll() is None:
            parent.kill()


def test_a_bundles_successor_list_is_checked() -> None:
    """The fast lane's successor list: ids above the bundle's robot, within the team, once."""
    from swarm.net.messages import BadMessage
    from world.config import WorldConfig

    cfg = WorldConfig(n_robots=4)
    for succ in (None, [], [2, 3]):
        assert Bundle.unpack(Bundle(0, 1, 1, [], succ).pack(), cfg).succ == succ
    for succ, why in (([1], "succ"), ([4], "succ"), ([2, 2], "repeats"), ("2", "list"),
                      ([2, 3, 3, 3], "list"), ([True], "succ")):
        with pytest.raises(BadMessage, match=why):
            Bundle.unpack(Bundle(0, 1, 1, [], succ).pack(), cfg)  # type: ignore[arg-type]



def test_a_childs_zenoh_flags_rebuild_the_supervisors_options(tmp_path: Path) -> None:
    """The supervisor hands each child its session as `ZenohOptions.to_args()` (one spelling of
    the flags, the one `add_arguments` parses): they come back as the same options."""
    import argparse

    from swarm.net import zconfig

    conf = tmp_path / "z.json5"
    conf.write_text("{}")
    for opts in (ZenohOptions("client", ["tcp/127.0.0.1:7447"]),
                 ZenohOptions("router", listen=["tcp/127.0.0.1:0", "tcp/127.0.0.1:7448"]),
                 ZenohOptions("router", ["tcp/10.0.0.1:7447"], ["tcp/10.0.0.2:7447"], str(conf),
                              ['transport/link/tx/lease:2000'])):
        parser = argparse.ArgumentParser()
        zconfig.add_arguments(parser, mode="router" if opts.mode == "peer" else "peer")
        assert zconfig.from_args(parser.parse_args(opts.to_args())) == opts

OTHER_THREAD = """
import signal, threading, time, zenoh
from swarm.common.spawn import terminate_as_interrupt
from swarm.net.inbox import Inbox
from swarm.net.zconfig import ZenohOptions
terminate_as_interrupt()
def elsewhere():
    time.sleep(1.0)
    signal.pthread_kill(threading.get_ident(), signal.SIGTERM)  # taken here, not by main
with zenoh.open(ZenohOptions().to_config()) as s, Inbox(s) as inbox:
    threading.Thread(target=elsewhere, daemon=True).start()
    t0 = time.monotonic()
    try:
        inbox.next(60.0)
        print("no interrupt")
    except KeyboardInterrupt:
        print(time.monotonic() - t0)
"""


def test_a_signal_another_thread_takes_still_ends_a_long_wait() -> None:
    """A supervisor's death (PDEATHSIG) or Ctrl-C may land on one of Zenoh's threads; the main
    thread, waiting 60 s for an event, still unwinds within a wait slice, not after 60 s (a
    world waiting for its robots once outlived its SIGKILLed supervisor that way)."""
    r = subprocess.run([sys.executable, "-c", OTHER_THREAD], cwd=ROOT, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert float(r.stdout.split()[-1]) < 10.0, r.stdout


@pytest.mark.procs
def test_every_played_episode_ends_in_exactly_one_learner_counter(tmp_path: Path) -> None:
    """played = trained + pending + stale_dropped + incomplete + rejected, in the result."""
    proc = start_run(tmp_path, "acct1", "--policy", "commattn", "--train", "--train-batch", "4",
                     "--episodes", "14", "--rollout-loss", "0.2",
                     toml="[learner]\njoin_timeout = 2\n")  # (default 5 s: the wait at the end)
    assert proc.wait(timeout=180) == 0, proc.stderr.read().decode()[-2000:]
    acc = json.loads((tmp_path / "r.json").read_text())["learner"]["accounting"]
    assert acc["played"] == 14 and acc["unaccounted"] == 0, acc
    assert acc["received"] == acc["played"]
    assert acc["trained"] % 4 == 0 and acc["incomplete"] >= 1  # rollout loss: records missing
    assert acc["trained"] + acc["pending"] + acc["stale_dropped"] + acc["incomplete"] + \
        acc["rejected"] == 14


BAD_INPUTS = [
    ["bench", "train", "--threads", "99999"], ["bench", "train", "--policy", "nearest-frontier"],
    ["bench", "env", "--batch", "99999999999"], ["bench", "env", "--batch", "1,,2"],
    ["bench", "rollout", "--workers", "99999"], ["bench", "env", "--json", "{tmp}"],
    ["bench", "policy", "--json", "/dev/null/x.json"],
    ["run", "--seed", "-1"], ["run", "--train-sync"], ["run", "--first-episode", "-5"],
    ["run", "--tick-timeout", "nan"],
    ["run", "--partition", "0-4/5-12"], ["run", "--crash", "20@5"], ["run", "--pace", "-1"],
    ["run", "--json", "{tmp}"], ["run", "--json", "/dev/null/x.json"],
    ["run", "--log-dir", "{tmp}/file"], ["run", "--policy", "commattn", "--checkpoint",
                                         "{tmp}/file"],
    ["run", "--policy", "commattn", "--checkpoint", "checkpoints/vain.pt"],
    ["run", "--policy", "commattn", "--checkpoint", "{tmp}/missing.pt"],
    ["run", "--run-id", "a/b"], ["run", "--loss", "2"], ["run", "--bandwidth", "lots"],
    ["world", "--run-id", "x", "--listen", "notanendpoint"],
    ["world", "--run-id", "x", "--zenoh-config", "/nonexistent.json5"],
    ["world", "--run-id", "x", "--cfg", 'mode:"bad'],
    ["world", "--run-id", "x", "--crash", "1@3"],  # (process faults: swarm run's supervisor's)
    ["train", "--out", ""], ["train", "--out", "{tmp}/file"],  # ("" was the current directory)
    ["train", "--resume", "--out", "{tmp}/nothing"],  # (a typo started a fresh run)
    ["train", "--out", "{tmp}/g", "--faults", "garbage"],
    ["train", "--out", "{tmp}/g", "--robots", "3", "--faults", '{"partition": "0-4/5-9"}'],
    ["train", "--out", "{tmp}/g", "--loss", "0.1", "--faults", '{"latency": "5ms"}'],
    ["eval", "--config", "{tmp}/types.toml"], ["eval", "--config", "{tmp}/height.toml"],
    ["eval", "--overflow", "drop"],  # (no cap: it did nothing, silently)
    ["repro", "table2", "--out", "{tmp}/r", "--checkpoint", "comattn=checkpoints/commattn.pt"],
    ["world", "--run-id", "x", "--config", "{tmp}/crash.toml"],
    ["learner", "--run-id", "x", "--out", "{tmp}/empty", "--resume"],
    ["learner", "--run-id", "x", "--out", "{tmp}/l", "--zenoh-mode", "client", "--connect",
     "tcp/127.0.0.1:1"],
    ["robot", "--id", "0", "--run-id", "x", "--zenoh-mode", "client", "--connect",
     "tcp/127.0.0.1:1", "--wait", "0.5"],  # (a client tries its router for --wait seconds)
    ["train", "--out", "{tmp}/t", "--lr", "nan"], ["train", "--out", "{tmp}/t", "--epochs", "0"],
    ["eval", "--policy", "nope"], ["eval", "--json", "{tmp}"], ["eval", "--seed", "-1"],
    ["eval", "--seed", "99999999999999999999"], ["bench", "policy", "--seed", "-1"],
    ["repro", "table1", "--out", "{tmp}/file"],  # (checked before the work, not after)
    ["repro", "comm", "--out", "{tmp}/r", "--comm-policies", "nope"],
    # (permission bits say "writable" for root here: the check writes a probe file)
    ["eval", "--json", "/proc/swarm.json"], ["run", "--train", "--learner-out", "/proc/swarm"],
    ["fault", "--run", "nosuchrun", "--loss", "0.1"],
    ["run", "--robots", "3", "--attention", "7"], ["run", "--robots", "3", "--hosts", "9"],
    ["eval", "--latency", "-5ms"], ["eval", "--bandwidth", "2kb/s"],
    ["eval", "--policy", "commattn", "--checkpoint", "README.md"],
    # an empty name was taken as "none" (--record, --log-dir: a run with neither, silently) or
    # as the working directory (certs: its keys written there and the directory made 0700)
    ["run", "--record", ""], ["run", "--log-dir", ""], ["run", "--json", ""],
    ["bench", "env", "--json", ""], ["bench", "swarm", "--json", "", "--robots", "2"],
    ["certs", "--out", "", "--robots", "1"],
    ["robot", "--id", "-1", "--run-id", "x"],  # (it waited 30 s for a world first)
    ["robot", "--id", "1000000", "--run-id", "x"],  # (no team is that large: as long a wait)
    # a config "file" that is a directory or not UTF-8 (exit 1; a 20-line traceback for the 2nd)
    ["eval", "--config", "{tmp}"], ["run", "--config", "{tmp}/latin.toml"],
    ["train", "--out", "{tmp}/t", "--config", "{tmp}/latin.toml"],
    # a run's process fault without its tick ("at once", before any robot was up: the run said
    # they were not up within the start timeout), from a flag or a file
    ["run", "--robots", "4", "--crash", "1"], ["run", "--config", "{tmp}/crash_now.toml"],
    ["eval", "--config", "{tmp}/robot_int.toml"], ["eval", "--config", "{tmp}/robot_list.toml"],
    # review helper 95: a traceback (a policy list of numbers, a scalar process fault), Python's
    # words (a robot key that is no id), an empty value run as not given, an output over a file
    # the command writes, a training file's faults past the flags' checks, one point twice
    ["repro", "table1", "--out", "{tmp}/ro", "--decisions", "1", "--config", "{tmp}/pol5.toml"],
    ["eval", "--config", "{tmp}/crash5.toml"], ["eval", "--config", "{tmp}/robotx.toml"],
    ["eval", "--policy", ",random", "--episodes", "1"],
    ["bench", "swarm", "--robots", "2", "--secure", ""],
    ["learner", "--run-id", "x", "--out", "{tmp}/L", "--checkpoint", ""],
    ["train", "--out", "{tmp}/t", "--faults", '{"overflow": "drop"}'],
    ["train", "--out", "{tmp}/t", "--faults", '{"partition": ""}'],
    ["certs", "--out", "{tmp}", "--robots", "1", "--json", "{tmp}/ca.pem"],
    ["run", "--log-dir", "{tmp}", "--json", "{tmp}/world.log"],
    ["experiment", "{tmp}/twice.toml", "--out", "{tmp}/x"],
    ["experiment", "{tmp}/twice.toml", "--out", "{tmp}", "--resume"],
]


@pytest.mark.procs
@pytest.mark.parametrize("args", BAD_INPUTS, ids=lambda a: " ".join(a)[:40])
def test_a_bad_input_is_one_line_a_nonzero_exit_and_nothing_left_running(
        tmp_path: Path, args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").write_text("not a checkpoint")
    (tmp_path / "crash.toml").write_text('[faults]\ncrash = ["1@3"]\n')
    (tmp_path / "types.toml").write_text("[eval]\ncheckpoint = 3\n")  # (a TypeError once)
    (tmp_path / "height.toml").write_text('[world]\nheight = "abc"\n')
    (tmp_path / "latin.toml").write_bytes(b"[world]\nheight = 20\n# caf\xe9\n")
    (tmp_path / "crash_now.toml").write_text("[world]\nn_robots = 4\n[faults]\ncrash = [1]\n")
    (tmp_path / "robot_int.toml").write_text('[faults.robot]\n"3" = 5\n')
    (tmp_path / "robot_list.toml").write_text("[faults]\nrobot = []\n")
    (tmp_path / "pol5.toml").write_text("[repro]\npolicies = [5]\n")
    (tmp_path / "crash5.toml").write_text("[faults]\ncrash = 5\n")
    (tmp_path / "robotx.toml").write_text("[faults.robot.x]\nloss = 0.1\n")
    values = "[0, 0.0]" if "{tmp}/x" in args else "[0, 0.1]"  # (--resume: no sweep there)
    (tmp_path / "twice.toml").write_text(f'[experiment]\nparameter = "loss"\nvalues = {values}'
                                         '\npolicies = ["random"]\nseeds = [0]\n')
    r = swarm_here(*(a.replace("{tmp}", str(tmp_path)) for a in args), capsys=capsys)
    assert r.returncode in (1, 2), (r.returncode, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("swarm: error: "), r.stderr
    assert " object " not in lines[0], r.stderr  # ("'int' object is not iterable")
    assert run_pids(str(tmp_path)) == []


@pytest.mark.procs
@pytest.mark.parametrize("args", [
    ["eval", "--robots", "2", "--episodes", "1", "--partition", ""],
    ["eval", "--robots", "2", "--episodes", "1", "--config", "{tmp}/part.toml"],
    ["run", "--robots", "1", "--episodes", "1", "--horizon", "5", "--static", "--partition",
     " "],
    ["world", "--robots", "1", "--episodes", "1", "--start-timeout", "5", "--spec", ""],
    ["world", "--robots", "1", "--episodes", "1", "--start-timeout", "5", "--zenoh-config", ""],
    ["router", "--listen", "tcp/127.0.0.1:0", "--zenoh-config", " "],
], ids=lambda a: " ".join(a)[:40])
def test_an_empty_value_is_refused_not_read_as_not_given(
        tmp_path: Path, args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """An empty partition ran with none (`0-1/`, an empty group, was refused); an empty --spec
    or --zenoh-config started a world by hand: one line, exit 2, before anything starts."""
    (tmp_path / "part.toml").write_text('[faults]\npartition = ""\n')
    r = swarm_here(*(a.replace("{tmp}", str(tmp_path)) for a in args), capsys=capsys)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "is empty" in r.stderr or "got an empty one" in r.stderr, r.stderr


LONG = "x" * 300  # one name over the file system's 255 bytes


@pytest.mark.procs
@pytest.mark.parametrize("args", [
    ["eval", "--robots", "2", "--episodes", "1", "--json", "{tmp}/" + LONG],
    ["eval", "--robots", "2", "--episodes", "1", "--episodes-csv", "{tmp}/" + LONG],
    ["run", "--json", LONG], ["run", "--record", LONG], ["run", "--secure", LONG],
    ["run", "--log-dir", "{tmp}/a/b/" + LONG], ["certs", "--out", LONG, "--robots", "1"],
    ["certs", "--out", "{tmp}/c", "--robots", "1", "--json", LONG],
    ["robot", "--id", "0", "--run-id", "x", "--secure", LONG],
    ["record", "--run-id", "x", "--out", LONG], ["experiment", LONG],
    ["experiment", "deploy/experiments/latency.toml", "--out", "{tmp}/a/" + LONG],
    ["train", "--policy", "commattn", "--out", LONG],  # (a traceback: it raised while parsing)
], ids=lambda a: " ".join(a)[:30])
def test_a_name_too_long_is_one_line_and_nothing_is_made(
        tmp_path: Path, args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """A path with a name over 255 bytes was the OS's "File name too long" with exit 1 (or a
    traceback, or after `--log-dir a/b/LONG` had made a/b): one line, exit 2, nothing made."""
    r = swarm_here(*(a.replace("{tmp}", str(tmp_path)) for a in args), capsys=capsys)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "255 bytes" in r.stderr or "File name too long" in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.procs
@pytest.mark.parametrize("policy, says", [
    (["--policy", "abc"], "unknown policy 'abc'"),
    (["--policy", "commattn", "--checkpoint", "checkpoints/vain.pt"], "holds policy 'vain'"),
], ids=["policy", "checkpoint"])
def test_a_hand_world_checks_its_policy_before_it_starts(
        policy: list[str], says: str, capsys: pytest.CaptureFixture[str]) -> None:
    """`swarm world` started and waited for robots with a policy `swarm run` refuses: it now
    refuses it in the same line (swarm.cli.checks.check_policy), exit 2, before listening."""
    from swarm.net.zconfig import free_port

    r = swarm_here("world", "--robots", "1", "--episodes", "1", "--start-timeout", "10",
                   "--run-id", "w1", *policy, "--listen", f"tcp/127.0.0.1:{free_port()}",
                   capsys=capsys)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and says in r.stderr, r.stderr


@pytest.mark.procs
def test_the_checked_flags_still_take_their_other_values() -> None:
    """`--attention off` (no robot id to check against the team) runs: the team-size check of
    `--attention` once compared None with an int."""
    r = swarm("run", "--headless", "--robots", "2", "--episodes", "1", "--horizon", "4",
              "--policy", "random", "--attention", "off", timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(r.stdout.strip().splitlines()[-1])["result"]["completed"] == 1


_BLAS_THREADS = """
import os, sys
if sys.argv[1] == "swarm":
    import swarm  # noqa: F401  (what every entry point imports first)
import numpy as np
a = np.ones((400, 400))
a @ a  # OpenBLAS starts its pool on first use
print(len(os.listdir("/proc/self/task")))
"""


@pytest.mark.skipif((os.cpu_count() or 1) < 2 or not Path("/proc/self/task").exists(),
                    reason="needs /proc and two cores (OpenBLAS starts one thread per core)")
def test_every_swarm_process_uses_one_blas_thread_unless_told_otherwise() -> None:
    """OpenBLAS's spare threads spin between calls: two trainings side by side each lost half
    their CPU to them. Importing `swarm` sets one thread before numpy loads; a choice already
    in the environment stands."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}

    def threads(how: str, **extra: str) -> int:
        out = subprocess.run([sys.executable, "-c", _BLAS_THREADS, how], env={**env, **extra},
                             cwd=ROOT, capture_output=True, text=True, check=True)
        return int(out.stdout)

    assert threads("numpy") > 1  # the default this guards against
    assert threads("swarm") == 1
    assert threads("swarm", OPENBLAS_NUM_THREADS="2") == 2


def test_stop_children_ends_every_child_even_when_popens_lock_was_lost() -> None:
    """A Ctrl-C landing inside Popen.poll can leave Popen's wait lock held (a supervisor then
    hung in stop_all's Popen.wait for good, its children zombies): `stop_children` reaps with
    os.waitpid, SIGKILLs what ignores SIGINT past the grace, and a Ctrl-C during the stop is
    raised only once every child is down."""
    from swarm.common.spawn import stop_children

    code = "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print(1, " \
        "flush=True); time.sleep(60)"
    stubborn = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    polite = subprocess.Popen([sys.executable, "-c", "import time; print(1, flush=True); "
                               "time.sleep(60)"], stdout=subprocess.PIPE)
    for p in (stubborn, polite):  # both running their sleep, the stubborn one ignoring SIGINT
        assert p.stdout is not None and p.stdout.readline()  # (a fixed 0.5 s was not enough
        # on a loaded machine: a SIGINT during the interpreter's start ended it with exit 1)
    assert stubborn._waitpid_lock.acquire(False)  # the lost lock: held, never released
    t0 = time.monotonic()
    stop_children([stubborn, polite], grace=0.5)
    assert time.monotonic() - t0 < 5
    assert stubborn.returncode == -signal.SIGKILL and polite.returncode not in (None, 0)
    for p in (stubborn, polite):
        with pytest.raises(ChildProcessError):
            os.waitpid(p.pid, os.WNOHANG)  # reaped: no zombie left

    sleeper = subprocess.Popen([sys.executable, "-c", code])
    time.sleep(0.5)
    old = signal.signal(signal.SIGALRM, lambda s, f: os.kill(os.getpid(), signal.SIGINT))
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.1)  # a Ctrl-C in the middle of the stop
        with pytest.raises(KeyboardInterrupt):
            stop_children([sleeper], grace=0.5)
    finally:
        signal.signal(signal.SIGALRM, old)
    assert sleeper.returncode == -signal.SIGKILL  # down before the interrupt was raised


def test_a_robot_takes_only_observations_and_ticks_that_fit_its_run() -> None:
    """In-range but out of sequence: an observation of another episode, going back, or farther
    than one move a tick from the last, and a bundle or hidden state far ahead (kept for ever
    before: a memory leak) are refused; what fits is taken (a new episode may start anywhere)."""
    from swarm.net.messages import BadMessage
    from swarm.procs.robot_status import TickGuard

    g = TickGuard(horizon=30, first_episode=2, episodes=3)
    g.obs(2, 0, 5, 5)
    g.obs(2, 3, 8, 2)  # three moves in three ticks
    for bad, words in (((2, 3, 8, 2), "after tick 3"), ((2, 4, 8, 4), "out of reach"),
                       ((9, 0, 1, 1), "not one of this run's"), ((2, 31, 8, 2), "horizon")):
        with pytest.raises(BadMessage, match=words):
            g.obs(*bad)
    g.tick(2, 4)  # the next tick's bundle may come early
    with pytest.raises(BadMessage, match="ahead"):
        g.tick(2, 6)
    with pytest.raises(BadMessage, match="ahead"):
        g.tick(3, 0)
    g.obs(3, 0, 0, 0)  # a new episode, anywhere
    g.tick(3, 1)


def test_a_world_status_must_fit_the_run_before_a_process_fault_fires_on_it() -> None:
    """The supervisor fires planned process faults on the status's run tick: a status must be
    of the run's episodes and team, and its run tick that of its episode and tick."""
    from swarm.net.messages import BadMessage
    from swarm.net.records import check_world_status
    from world.config import WorldConfig

    cfg = WorldConfig(n_robots=3)
    ok = {"ep": 3, "t": 5, "run_tick": 35, "pos": [[0, 0], [1, 1], [2, 2]],
          "alive": [True, False, True], "elratio": 0.5, "timeouts": [1], "dyn": [[4, 4]]}
    assert check_world_status(dict(ok), cfg, first_episode=2, episodes=4) == ok
    for change, words in (({"run_tick": 110}, "not episode 3 tick 5"),
                          ({"ep": 9}, "status ep"), ({"pos": [[0, 0]] * 500}, "at most 3"),
                          ({"alive": [True] * 500}, "3 booleans"), ({"elratio": 7.5}, "elratio"),
                          ({"timeouts": list(range(1000))}, "timeouts"),
                          # what the dashboard and `swarm trace` index: a short link crashed
                          # the supervisor's display and `swarm replay`, a number in the
                          # fault lines their join
                          ({"links": {"0-1": [1]}}, 'status links: .0-1. is no "SENDER-'),
                          ({"links": {"0-7": [1, 2, 3, 4]}}, "no \"SENDER-RECEIVER\""),
                          ({"links": {"0-1": [1, -2, 3, 4]}}, "status links 0-1"),
                          ({"links": {"0-1": [1, 2.5, 3, 4]}}, "status links 0-1"),
                          ({"links": {"0-1": [1, "2", 3, 4]}}, "status links 0-1"),
                          ({"links": {"0-1": [1, 2, 3, 2 ** 70]}}, "status links 0-1"),
                          ({"links": {7: [1, 2, 3, 4]}}, "no \"SENDER-RECEIVER\""),
                          ({"links": {"00-1": [1, 2, 3, 4]}}, "no \"SENDER-RECEIVER\""),
                          ({"links": {"0-1": (1, 2, 3, 4)}}, "no \"SENDER-RECEIVER\""),
                          ({"links": [1, 2]}, "at most 9 links"),
                          ({"faults": [1, 2]}, "64 lines of text"),
                          ({"radio": {"lost": "many"}}, "status radio"),
                          ({"radio": {"lost": float("nan")}}, "status radio")):
        with pytest.raises(BadMessage, match=words):
            check_world_status({**ok, **change}, cfg, first_episode=2, episodes=4)
    panels = {"faults": ["all: loss 0.3"], "links": {"0-1": [5, 1, 0, 2]},
              "radio": {"lost": 3, "by_kind": {"traj": {"lost": 3}}, "reported": [0, 2],
                        "restarted": [{"robot": 0, "reported_to": [2, 3]}] * 5}}  # (> n)
    assert check_world_status({**ok, **panels}, cfg, first_episode=2, episodes=4)
    # what the world sends of its fault plan fits, however large (a partition of 128 robots
    # or 64 robots' own faults made every status too big for its readers)
    from swarm.net.faults import plan_from_table

    big = WorldConfig(n_robots=200)
    plan = plan_from_table({"partition": "0-99/100-199", "crash": [f"{r}@9" for r in range(80)],
                            "robot": {str(r): {"loss": 0.1} for r in range(30)}}, 0, 200)
    lines = plan.panel()
    assert len(lines) == 64 and lines[-1] == f"... {len(plan.describe()) - 63} more"
    assert any(x.startswith("partition 0,1,") and x.endswith("...") for x in lines)
    pos = [[0, r % 20] for r in range(200)]
    assert check_world_status({**ok, "pos": pos, "alive": [True] * 200, "timeouts": [],
                               "faults": lines}, big, first_episode=2, episodes=4)


def test_link_keys_of_a_large_team_are_parsed_as_the_small_ones_are_looked_up(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Past LINK_KEYS_HELD robots a status's link keys are parsed, not looked up in a set of
    every key (10^6 strings for 1,000 robots): both ways take and refuse the same keys."""
    from swarm.net import records
    from swarm.net.messages import BadMessage

    keys = ["0-1", "19-0", "20-1", "1-20", "01-2", "0-01", "-1-2", "1-2-3", "1-", "-", "",
            "\uff11-2", "+1-2", " 1-2", "1-2 ", "1_0-2", "7", "99999999999999999999999-1",
            "1-2\n3-4", "1-2\n"]
    small = [records._is_link_key(k, 20) for k in keys]
    assert small == [True, True] + [False] * 18
    assert [records._parsed_keys({k: 1}, 20) for k in keys] == small
    assert records._parsed_keys(dict.fromkeys(keys[:2]), 20)
    assert not records._parsed_keys(dict.fromkeys(keys[:3]), 20)
    monkeypatch.setattr(records, "LINK_KEYS_HELD", 0)
    assert [records._is_link_key(k, 20) for k in keys] == small
    assert not records._is_link_key(7, 20)
    monkeypatch.undo()
    team = 300
    records._link_keys.cache_clear()
    assert team > records.LINK_KEYS_HELD
    links = {f"{j}-{(j + 1) % team}": [1, 2, 3, 4] for j in range(team)}
    records._status_panels({"links": links}, team)
    for bad in ("300-1", "03-1", "1-2-3", "\uff11-2", "1-2\n3-4", 5):
        with pytest.raises(BadMessage, match="SENDER-RECEIVER"):
            records._status_panels({"links": {**links, bad: [1, 2, 3, 4]}}, team)
    assert records._link_keys.cache_info().currsize == 0  # (no set of 90,000 keys made)


def test_swarm_version_names_the_package_and_the_commit(
        capsys: pytest.CaptureFixture[str]) -> None:
    """`swarm --version` (there was none): the installed version and the source tree's commit,
    as a result's `provenance` names them."""
    from swarm.common.report import provenance

    r = swarm_here("--version", capsys=capsys)
    assert r.returncode == 0, r.stderr
    git = provenance()["git"]
    assert r.stdout.startswith("swarm 0.1.0") and (git is None or git in r.stdout), r.stdout


@pytest.mark.procs
def test_a_hand_robot_whose_world_dies_says_so(tmp_path: Path) -> None:
    """`swarm robot` started by hand, its world SIGKILLed mid-run: one warning line that the
    world left before the run's end (it exited 0 without a word, as after a whole run) and exit
    status 3, not the 0 of a run that ended."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        hub = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    world = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "world", "--run-id", "handgone", "--robots", "1",
         "--policy", "nearest-frontier", "--episodes", "200", "--pace", "5", "--listen", hub],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    robot = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "robot", "--id", "0", "--run-id", "handgone",
         "--connect", hub], cwd=ROOT, stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(6)  # (the run started: a robot acts once the world is up)
        assert world.poll() is None and robot.poll() is None, robot.communicate()[1]
        world.kill()
        _, err = robot.communicate(timeout=60)
    finally:
        for p in (world, robot):
            if p.poll() is None:
                p.kill()
    assert "the world left before the run's end" in err, err
    said = [line for line in err.splitlines() if line.startswith("swarm robot:")]
    assert robot.returncode == 3 and len(said) == 1 and "run handgone" in said[0], err
    assert "Traceback" not in err, err


def test_a_client_waits_only_while_nothing_listens() -> None:
    """A client retries its open only while no TCP listener answers at its endpoints: a
    listening router that refuses it (another CA's certificate) is said at once, not after the
    whole --wait as if nobody were there (review helper 101)."""
    import socket

    from swarm.net.zconfig import _listening

    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        port = srv.getsockname()[1]
        assert _listening(f"tcp/127.0.0.1:{port}") and _listening(f"tls/127.0.0.1:{port}")
    assert not _listening(f"tcp/127.0.0.1:{port}")  # (closed now)
    assert _listening("quic/127.0.0.1:1") and _listening("udp/127.0.0.1:1")  # (no handshake)
    assert not _listening("tcp/not a host:7447")


@pytest.mark.procs
def test_a_client_robot_typed_before_its_world_waits_for_it() -> None:
    """`swarm robot --zenoh-mode client` started before its world's router listens (two
    commands typed back to back): it tries again for its --wait, joins and plays the run (Zenoh
    fails a client's open at once: it exited 1 in a second, whatever --wait said)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        hub = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    robot = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "robot", "--id", "0", "--run-id", "early",
         "--zenoh-mode", "client", "--connect", hub, "--wait", "60"], cwd=ROOT,
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    world = None
    try:
        time.sleep(2.0)  # (the robot is up and finds nobody listening)
        assert robot.poll() is None, robot.communicate()[1]
        world = subprocess.Popen(
            [sys.executable, "-m", "swarm.cli", "world", "--run-id", "early", "--robots", "1",
             "--policy", "nearest-frontier", "--episodes", "1", "--zenoh-mode", "router",
             "--listen", hub], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            text=True)
        _, err = robot.communicate(timeout=120)
        _, werr = world.communicate(timeout=60)
    finally:
        for p in (robot, world):
            if p is not None and p.poll() is None:
                p.kill()
    assert robot.returncode == 0, err[-1500:]
    assert world.returncode == 0, werr[-1500:]
    # interrupted while it waits for its router: one line and 130, as every command
    robot = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "robot", "--id", "0", "--run-id", "early",
         "--zenoh-mode", "client", "--connect", hub, "--wait", "60"], cwd=ROOT,
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(2.0)
        robot.send_signal(signal.SIGINT)
        _, err = robot.communicate(timeout=30)
    finally:
        if robot.poll() is None:
            robot.kill()
    assert robot.returncode == 130 and err.strip() == "swarm: interrupted", err


@pytest.mark.procs
def test_a_hand_world_stopped_by_ctrl_c_says_so() -> None:
    """`swarm world` by hand, Ctrl-C'd while it waits for its robots: exit 130 and the line
    `swarm run` gives (it exited 130 without a word; UA pass 43)."""
    world = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "world", "--run-id", "handint", "--robots", "2"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert world.stderr is not None
        assert world.stderr.readline().startswith("swarm world: run id handint")
        time.sleep(1.0)  # (its session open, waiting for robots)
        world.send_signal(signal.SIGINT)
        _, err = world.communicate(timeout=30)
    finally:
        if world.poll() is None:
            world.kill()
    assert world.returncode == 130 and err.strip().splitlines()[-1] == "swarm: interrupted", err


def test_a_refused_run_makes_no_folder_and_a_byte_path_is_shown_escaped(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Review helper 95: `swarm run --log-dir NEW` refused by a later check had made NEW (and
    `repro --out NEW --json BAD` its NEW); a path holding a byte that is no UTF-8 crashed the
    tables' "Made by" line after the work, leaving a CSV without its Markdown."""
    from conftest import swarm_here

    new = tmp_path / "new" / "a"
    r = swarm_here("run", "--robots", "2", "--policy", "commattn", "--checkpoint",
                   "checkpoints/vain.pt", "--log-dir", str(new), capsys=capsys)
    assert r.returncode == 2 and not (tmp_path / "new").exists(), r.stderr
    for json_path in (tmp_path / "no" / "x.json", tmp_path):  # (checked before --log-dir made)
        r = swarm_here("run", "--robots", "2", "--log-dir", str(new), "--json", str(json_path),
                       capsys=capsys)
        assert r.returncode == 2 and not (tmp_path / "new").exists(), r.stderr
    for json_path in (tmp_path / "no" / "x.json", new / "sub" / "x.json"):
        r = swarm_here("repro", "table1", "--out", str(new), "--json", str(json_path),
                       capsys=capsys)
        assert r.returncode == 2 and not (tmp_path / "new").exists(), r.stderr
    odd = tmp_path / "caf\udce9"  # (the byte 0xe9 of a Latin-1 name, as Python reads argv)
    done = subprocess.run([sys.executable, "-m", "swarm.cli", "repro", "table1", "--out",
                           str(odd), "--policies", "random", "--decisions", "1"], cwd=ROOT,
                          capture_output=True, timeout=120, check=False)  # (bytes: the path)
    assert done.returncode == 0, done.stderr[-800:]
    assert "caf\\xe9" in (odd / "table1.md").read_text()
