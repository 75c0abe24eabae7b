"""The virtual clock: a swarm run under faults is a pure function of its seed and fault plan,
equal to the batched evaluator tick by tick, whatever the host's load."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, swarm

from policies import make_policy
from swarm.learn.evaluate import evaluate
from swarm.net.faults import plan_from_table
from world.config import ConfigError, WorldConfig

CKPT = str(ROOT / "checkpoints" / "commattn.pt")
# each fault kind, and all of them at once; tick 0.2 virtual seconds: traj deadline 160 ms,
# hidden-state deadline 180 ms
KINDS = {
    "loss": {"loss": "0.3"},
    "latency": {"latency": "120ms", "jitter": "60ms"},
    "bandwidth": {"bandwidth": "400B/s", "burst": 200},
    "partition": {"partition": "0-1/2-3"},
    "compute": {"compute-ms": "150", "latency": "15ms"},
    "mix": {"loss": "0.2", "latency": "120ms", "jitter": "60ms", "bandwidth": "800B/s",
            "overflow": "expire", "partition": "0/1-3"},  # (queue: "bandwidth")
}


def _flags(table: dict[str, object]) -> list[str]:
    out = []
    for k, v in table.items():
        out += [f"--{k}", str(v)] if k != "burst" else []
    return out


def _run(tmp: Path, name: str, policy: str, faults: dict[str, object], *extra: str) -> dict:
    cfg = tmp / f"{name}.toml"
    burst = f"burst = {faults['burst']}\n" if "burst" in faults else ""
    cfg.write_text(f"[run]\ntick_timeout = 0.2\n[faults]\nseed = 5\n{burst}")
    args = ["run", "--headless", "--robots", "4", "--policy", policy, "--episodes", "2",
            "--seed", "3", "--run-id", name, "--json", str(tmp / f"{name}.json"), "--config",
            str(cfg), *_flags(faults), *extra]
    if policy == "commattn":
        args += ["--checkpoint", CKPT]
    r = swarm(*args, timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads((tmp / f"{name}.json").read_text())


def _batched(policy: str, faults: dict[str, object], episodes: int = 2) -> np.ndarray:
    world = WorldConfig(n_robots=4)
    table = {("compute" if k == "compute-ms" else k): (f"{v}ms" if k == "compute-ms" else v)
             for k, v in faults.items()}
    table["seed"] = 5
    pol = make_policy(policy, world, **({"checkpoint": CKPT} if policy == "commattn" else {}))
    res = evaluate(world, pol, 3, episodes, batch=2, record_actions=True,
                   faults=plan_from_table(table, 3), tick_s=0.2)
    return np.stack(res.actions, 1)  # [episodes, T, N]


@pytest.fixture(scope="module")
def loaded_mix_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, dict]:
    """Two equal CommAttn runs under every fault at once ("mix"), played one after the other
    while a process keeps a core busy: test_two_virtual_runs_agree_while_the_cpu_is_loaded
    compares them, and the first is the ("commattn", "mix") case of
    test_virtual_swarm_equals_batched_eval_under_each_fault (one run fewer)."""
    tmp = tmp_path_factory.mktemp("hog")
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        return _run(tmp, "hoga", "commattn", KINDS["mix"]), _run(tmp, "hogb", "commattn",
                                                                  KINDS["mix"])
    finally:
        hog.kill()


@pytest.mark.procs
@pytest.mark.parametrize("policy,kind", [("nearest-frontier", k) for k in KINDS]
                         + [("commattn", "mix"), ("commattn", "latency"), ("chain-plan", "mix")])
def test_virtual_swarm_equals_batched_eval_under_each_fault(tmp_path: Path,
                                                            request: pytest.FixtureRequest,
                                                            policy: str, kind: str) -> None:
    episodes = 1 if policy == "chain-plan" else 2  # (its robots' searches are slow)
    if (policy, kind) == ("commattn", "mix"):  # (its run is one of `loaded_mix_runs`, 2 episodes)
        res = request.getfixturevalue("loaded_mix_runs")[0]
    else:
        res = _run(tmp_path, f"v{kind}{policy[:4]}", policy, KINDS[kind], "--episodes",
                   str(episodes))
    assert res["clock"] == "virtual" and res["timeouts"] == 0
    swarm_actions = np.array(res["actions"])
    assert np.array_equal(swarm_actions, _batched(policy, KINDS[kind], episodes)), {
        k: res.get(k) for k in ("never_joined", "robot_crashes", "robots_lost", "logs")}
    assert res["fast_lane_ticks"] == 0  # link faults: every hidden-state copy via the radio
    m = res["messages"]
    if kind in ("latency", "bandwidth", "compute", "mix"):
        assert m["late"] + m["dropped_bw"] > 0  # the plan bites: some copies came too late
    if kind in ("loss", "mix"):
        assert m["lost"] > 0
    if policy == "commattn" and kind == "mix":  # its states outgrow the cap: some expire
        assert m["dropped_bw"] > 0


@pytest.mark.procs
def test_hidden_states_that_waited_for_tokens_count_as_queued(tmp_path: Path) -> None:
    """Under a 150 B/s cap CommAttn's 266-byte hidden states wait in their senders' queues:
    counted queued per kind by the radio and by direct delivery alike, and the run still takes
    its batched twin's actions."""
    faults = {"bandwidth": "150B/s"}
    radio = _run(tmp_path, "hqr", "commattn", faults)
    direct = _run(tmp_path, "hqd", "commattn", faults, "--delivery", "direct")
    hidden = radio["messages"]["by_kind"]["hidden"]
    assert hidden["late"] > 0 and hidden["queued"] >= hidden["late"]  # no latency: the queue
    assert direct["messages"]["by_kind"] == radio["messages"]["by_kind"]
    assert np.array_equal(np.array(radio["actions"]), _batched("commattn", faults))


@pytest.mark.procs
def test_two_virtual_runs_agree_while_the_cpu_is_loaded(loaded_mix_runs: tuple[dict, dict]
                                                        ) -> None:
    a, b = loaded_mix_runs  # (played while a process kept a core busy)
    assert a["actions"] == b["actions"]
    for key in ("lost", "late", "cut", "dropped_bw", "traj_delivered", "hidden_delivered"):
        assert a["messages"][key] == b["messages"][key], key
    # each robot's counts are its last status's (sent at the end), not a snapshot of the run,
    # and equal run to run (the last observation could come after the end record, and the
    # world could close before a robot's last status had passed through it)
    for res in (a, b):
        assert all(c["final"] for c in res["robot_status"].values()), res["robot_status"]
    for r, c in a["robot_status"].items():
        for key in ("msgs_in", "msgs_out", "missed", "missed_hidden", "stale", "bad", "errors"):
            assert c[key] == b["robot_status"][r][key], (r, key)


def _cmdline(proc_dir: Path) -> bytes:
    """A process's command line; empty once it has ended (a process of another test, say,
    gone between listing /proc and reading it: CI failed so)."""
    try:
        return (proc_dir / "cmdline").read_bytes()
    except OSError:
        return b""


@pytest.mark.procs
def test_a_stopped_robot_is_caught_by_the_watchdog(tmp_path: Path) -> None:
    """A robot that stops unplanned (SIGSTOP from outside, no fault plan knows it) misses its
    ticks, counted as timeouts until its lease runs out (then it is lost); the others do not
    (they used to time out with it: tests/test_hardening.py, hung robot)."""
    out = tmp_path / "r.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "4", "--policy",
         "nearest-frontier", "--episodes", "2", "--seed", "3", "--run-id", "wdog", "--pace",
         "20", "--watchdog", "0.5", "--json", str(out)], cwd=ROOT, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # a few ticks in, stop robot 2 as a hung process would be
            if line.startswith('{"status"') and json.loads(line)["status"]["t"] >= 4:
                break
        robot = next(p for p in Path("/proc").iterdir() if p.name.isdigit() and
                     b"wdog" in _cmdline(p) and b"robot\0--id\0" + b"2" in _cmdline(p))
        os.kill(int(robot.name), signal.SIGSTOP)
        proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    res = json.loads(out.read_text())
    assert res["completed"] == 2 and res["timeouts"] >= 1
    acts = np.array(res["actions"])
    assert (acts[:, 10:, 2] == 0).all() and (acts[:, 10:, :2] != 0).any()


@pytest.mark.procs
def test_process_faults_land_on_their_tick_and_a_run_repeats_itself(tmp_path: Path) -> None:
    """Virtual clock: a crash, a hang and their restarts take effect at exactly their run tick
    (the world holds the robot down from it and waits for a restarted one to come up), so two
    runs are equal action for action; a restart used to come back 40-90 ticks late, or never,
    and a hang sometimes cost a watchdog's wait (UA pass)."""
    runs, rec = [], tmp_path / "proc.mcap"
    for k in range(2):
        res = _run(tmp_path, f"proc{k}", "nearest-frontier", {}, "--crash", "1@10",
                   "--restart", "1@15", "--hang", "2@20", "--restart", "2@24", "--crash",
                   "3@0", "--crash", "0@5", "--restart", "0@5",  # (0: a new process at 5)
                   "--hang", "1@30", "--restart", "1@33",  # (episode 1's first tick)
                   *(["--record", str(rec)] if k == 0 else []))
        runs.append(res)
        acts = np.array(res["actions"])  # [episode, tick, robot]
        assert (acts[0, 10:15, 1] == 0).all() and acts[0, 15:, 1].any()  # down, then back
        assert (acts[1, :3, 1] == 0).all() and acts[1, 3:, 1].any()
        assert (acts[0, 20:24, 2] == 0).all() and acts[0, 24:, 2].any()
        assert not acts[..., 3].any()  # down from tick 0: it never acted
        assert acts[0, 5:, 0].any()  # the new process acts from tick 5
        assert res["timeouts"] == 0 and res["robot_restarts"] == 4 and res["robots_lost"] == 1
        assert res["robot_crashes"] == 3  # 0's too: its restart of the same tick replaced it
        assert "child_errors" not in res  # (before the supervisor looked: it was not counted)
        assert res["process_faults"] == ["crash 3@0", "crash 0@5", "restart 0@5", "crash 1@10",
                                         "restart 1@15", "hang 2@20", "restart 2@24",
                                         "hang 1@30", "restart 1@33"]
    assert runs[0]["actions"] == runs[1]["actions"]
    # a fault of an episode's first tick was applied while the last one was still scored (its
    # metrics over one robot fewer): the recording did not verify (UA pass 67)
    r = swarm("replay", str(rec), "--verify")
    assert r.returncode == 0, r.stderr[-1500:]
    assert runs[0]["elratio_mean"] == runs[1]["elratio_mean"]


@pytest.mark.procs
def test_a_planned_hang_is_no_robot_that_left_the_run(tmp_path: Path) -> None:
    """A hang of the plan held to the run's end was said as "robots [1] left the run before
    its end" (a crash was not): the robot's lease ran out because the run stopped it."""
    out = tmp_path / "h.json"
    r = swarm("run", "--headless", "--robots", "3", "--policy", "nearest-frontier", "--episodes",
              "1", "--horizon", "8", "--hang", "1@4", "--json", str(out), timeout=120)
    assert r.returncode == 0 and "left the run" not in r.stderr, r.stderr[-1500:]
    assert json.loads(out.read_text())["process_faults"] == ["hang 1@4"]


@pytest.mark.procs
def test_restart_crashed_brings_a_planned_crash_back_at_the_next_tick(tmp_path: Path) -> None:
    """With `--restart-crashed` a crash of the plan at tick t is followed by a restart at t + 1
    (the supervisor respawns the process; the world waits for it there): the robot was
    respawned but held down for good, its run equal to one without the flag (UA pass)."""
    res = _run(tmp_path, "rcrash", "nearest-frontier", {}, "--crash", "1@10",
               "--restart-crashed")
    acts = np.array(res["actions"])  # [episode, tick, robot]
    assert (acts[0, 10, 1] == 0) and acts[0, 11:, 1].any() and acts[1, :, 1].any()
    assert res["robot_restarts"] == 1 and res["robots_lost"] == 0 and res["timeouts"] == 0


@pytest.mark.procs
def test_a_live_fault_change_lands_on_the_named_tick(tmp_path: Path) -> None:
    run_id = "livetick"
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "4", "--policy",
         "nearest-frontier", "--episodes", "3", "--run-id", run_id, "--pace", "20"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lost_at: dict[int, int] = {}
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if not line.startswith('{"status"'):
                continue
            st = json.loads(line)["status"]
            lost_at[st["run_tick"]] = st["radio"]["lost"]
            if st["run_tick"] == 5:
                r = swarm("fault", "--run", run_id, "--loss", "1", "--at-tick", "60", timeout=30)
                # (2.75 s ahead at 20 ticks/s: at tick 40 a loaded machine's `swarm fault`
                # came after the run had passed it, and was refused)
                assert r.returncode == 0, r.stderr
        assert proc.wait(timeout=120) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    # run tick k's status is written after tick k-1 is stepped: copies of tick 60 are in 61
    assert lost_at[60] == 0 and lost_at[61] > 0
    time.sleep(0)


@pytest.mark.procs
def test_train_takes_the_fault_flags_of_run_and_eval(tmp_path: Path) -> None:
    """`swarm train --latency ... --loss ...` trains under the radio's virtual-time model and the
    plan is part of the checkpoint (resume reproduces it)."""
    import torch

    from swarm.learn.config import TrainConfig
    from swarm.learn.rollout import train_faults

    r = swarm("train", "--policy", "commnet", "--robots", "3", "--out", str(tmp_path / "t"),
              "--epochs", "1", "--updates", "1", "--batch", "2", "--val-episodes", "0",
              "--threads", "1", "--latency", "150ms", "--jitter", "50ms", "--loss", "0.2",
              "--tick-s", "0.2", timeout=120)
    assert r.returncode == 0, r.stderr
    tr = torch.load(tmp_path / "t" / "checkpoint.pt", weights_only=False)["train"]["config"]
    plan = train_faults(TrainConfig(**tr))
    assert plan is not None and plan.default.latency_ms == 150 and plan.default.loss == 0.2
    assert tr["tick_s"] == 0.2


@pytest.mark.parametrize("table", [
    {"loss": 0.3, "latency": "400ms", "jitter": "300ms"},
    {"bandwidth": "300B/s", "burst": 400, "overflow": "drop", "loss": 0.1},
    {"bandwidth": "200B/s", "burst": 300, "partition": "0-3/4-9"},
    {"bandwidth": "250B/s", "overflow": "expire", "compute": "300ms", "latency": "200ms"},
])
def test_one_hidden_message_at_a_time_equals_the_batched_channel(table: dict) -> None:
    """The world decides each hidden-state message as it arrives (`hidden_from`, O(N)); the
    evaluator decides a tick's at once (`hidden`): the same fates, buckets charged alike."""
    from swarm.net.channel import VirtualChannel
    from swarm.net.faults import plan_from_table

    plan = plan_from_table(table, 5, 10)
    one, batch = VirtualChannel(plan, 10, 2.0), VirtualChannel(plan, 10, 2.0)
    rng = np.random.default_rng(0)
    for t in range(12):
        sizes = rng.integers(100, 400, (1, 10)).astype(float)
        senders = rng.random((1, 10)) < 0.8
        for ch in (one, batch):
            ch.traj(np.array([3]), t, senders, sizes)
        hs = rng.integers(200, 300, (1, 10)).astype(float)
        want = batch.hidden(np.array([3]), t, senders, hs).fate[0]
        for j in np.flatnonzero(senders[0]):
            assert np.array_equal(one.hidden_from(3, t, int(j), float(hs[0, j]))[0], want[:, j])


def test_a_live_restart_without_a_tick_releases_a_robot_a_planned_crash_holds() -> None:
    """`--crash 2@10` then `swarm fault --restart 2` (no tick): the world held robot 2 down for
    good, since only faults with a tick were gated; a live one now lands on the next tick."""
    from swarm.net.faults import ProcessFault
    from swarm.net.presence import Presence

    p = Presence(3, [ProcessFault("crash", 2, 10)], gated=True)
    for r in range(3):
        p.token(r, True)
    assert p.due(10) == [] and 2 not in p.live
    p.token(2, False)  # the SIGKILL lands
    p.add([ProcessFault("restart", 2, -1)], now=14)
    assert p.due(13) == [] and p.due(14) == [2]  # restarted at 14: the world waits for it
    p.token(2, True)  # the new process
    assert 2 in p.live and p.alive[2]


def test_the_world_drops_a_process_fault_change_as_its_supervisor_does() -> None:
    """With MAX_PENDING signals queued the supervisor drops a change whole (counted in
    process_faults_dropped) and never sends it; the world took it anyway and held the robot
    down for the rest of the run. Both queues fed the same control records agree now."""
    from swarm.net.faults.control import MAX_PENDING, check_control
    from swarm.net.messages import K_CONTROL, pack_record
    from swarm.net.presence import Presence
    from swarm.procs.runconfig import RunConfig
    from swarm.procs.supervisor import SuperviseOptions, Supervisor

    sup = Supervisor(WorldConfig(n_robots=3, horizon=100), RunConfig(run_id="qdrop", episodes=1),
                     SuperviseOptions(headless=True))
    world = Presence(3, (), gated=True)  # the world's, as WorldProcess._handle feeds it
    try:
        recs = [{"process": [f"restart:0@{50 + k}"]} for k in range(MAX_PENDING)]
        for rec in [*recs, {"process": ["hang:2@40"]}, {"process": ["crash:1"]}]:
            sup._handle("control", sup.keys.control, pack_record(K_CONTROL, rec))
            world.add(check_control(rec, 0, 3).process, now=10, limit=MAX_PENDING)
    finally:
        shutil.rmtree(sup.tmp, ignore_errors=True)
    assert sup.process_faults_dropped == 2 and len(sup.process_faults) == MAX_PENDING
    assert world.queued == MAX_PENDING
    for r in range(3):
        world.token(r, True)
    world.due(40)
    assert not world.held(2) and not world.held(1)


def test_a_predecessors_slot_in_virtual_time_is_at_least_half_the_budget() -> None:
    """On the real clock robot r waits for its predecessor until (r + 1) / N of the way to its
    deadline (a lost message costs one slot, never the whole budget downstream). In virtual time
    a lost or late message is said at once, so a slot runs out only on a stalled predecessor:
    robot 1 of 12 gave up after 2/12 of the watchdog, and a stall that long on a loaded machine
    changed its decision with no timeout counted (review helper 99). The slots spread over the
    second half of the budget there, a slot apart; a new run's watchdog under MIN_WATCHDOG_S is
    refused."""
    from swarm.procs.robot import VIRTUAL_HOP_FLOOR
    from swarm.procs.robot_status import hop_deadline
    from swarm.procs.runconfig import MIN_WATCHDOG_S, RunConfig, RunRecord, check_new_run

    assert hop_deadline(0.0, 12.0, 1, 12) == 2.0  # the real clock's slots
    assert hop_deadline(0.0, 12.0, 10, 12) == 11.0
    assert hop_deadline(0.0, 12.0, 1, 12, VIRTUAL_HOP_FLOOR) == 7.0  # 0.5 + 0.5 * 2 / 12
    assert hop_deadline(0.0, 12.0, 11, 12, VIRTUAL_HOP_FLOOR) == 12.0
    slots = [hop_deadline(0.0, 1.0, r, 12, VIRTUAL_HOP_FLOOR) for r in range(12)]
    # a slot apart each: a predecessor that gave up at its slot still reaches its successor
    # in time (a floor shared by the early robots broke every link behind one stalled robot)
    assert all(b - a > 0.04 for a, b in zip(slots, slots[1:], strict=False)) and slots[0] > 0.5
    assert check_new_run(RunConfig(watchdog=MIN_WATCHDOG_S)).watchdog == 0.5
    with pytest.raises(ConfigError, match=r"watchdog must lie in \[0.5, 3600.0\], got 0.25"):
        check_new_run(RunConfig(watchdog=0.25))
    # a recording of a run that took a shorter one still reads (replay, verify, trace)
    assert RunRecord.from_record({"world": {}, "run": {"watchdog": 0.25}}).run.watchdog == 0.25
