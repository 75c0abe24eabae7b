"""The distributed swarm with real processes and real Zenoh sessions on loopback (scouting off)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zenoh
from conftest import CYCLIC_PLUGIN, ROOT, swarm, swarm_started

from policies import make_policy
from swarm.learn.evaluate import evaluate
from swarm.net.keys import Keys
from swarm.net.zconfig import ZenohOptions
from world.config import WorldConfig


def run_procs(run_id: str) -> list[int]:
    """PIDs of live processes whose command line mentions the run id."""
    pids = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            stat = (d / "stat").read_text().split()
        except OSError:
            continue
        if run_id in cmd and stat[2] != "Z" and int(d.name) != os.getpid():
            pids.append(int(d.name))
    return pids


@pytest.fixture(scope="module")
def side_by_side(tmp_path_factory: pytest.TempPathFactory
                 ) -> dict[str, tuple[set[Path], subprocess.CompletedProcess[str], Path]]:
    """Two nearest-frontier runs of 2 episodes played at once, for two tests (one run fewer
    than each playing its own): `eqnear` (4 robots, seed 11) is the nearest-frontier case of
    test_swarm_run_matches_batched_eval_tick_by_tick, `sideB` (3 robots, seed 4) its neighbour
    for test_two_runs_side_by_side_do_not_cross_talk. Per run id: the run's temp folders before
    it started, its exit status, stdout and stderr, and its result file."""
    tmp, temp = tmp_path_factory.mktemp("side"), Path(tempfile.gettempdir())
    procs: dict[str, tuple[set[Path], subprocess.Popen[str]]] = {}
    try:
        for run_id, robots, seed in (("eqnear", 4, 11), ("sideB", 3, 4)):
            before = set(temp.glob(f"swarm-{run_id}-*"))
            with open(tmp / f"{run_id}.out", "w") as out, open(tmp / f"{run_id}.err", "w") as err:
                procs[run_id] = before, subprocess.Popen(
                    [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots",
                     str(robots), "--policy", "nearest-frontier", "--episodes", "2", "--seed",
                     str(seed), "--run-id", run_id, "--json", str(tmp / f"{run_id}.json")],
                    cwd=ROOT, stdout=out, stderr=err, text=True)
        runs = {}
        for run_id, (before, proc) in procs.items():
            code = proc.wait(timeout=120)
            runs[run_id] = before, subprocess.CompletedProcess(
                proc.args, code, (tmp / f"{run_id}.out").read_text(),
                (tmp / f"{run_id}.err").read_text()), tmp / f"{run_id}.json"
        return runs
    finally:
        for _, proc in procs.values():
            if proc.poll() is None:
                proc.kill()


@pytest.mark.procs
@pytest.mark.parametrize("policy,episodes", [("nearest-frontier", 2), ("team-beam", 2),
                                             ("chain-plan", 1)])  # (chain-plan's are slow)
def test_swarm_run_matches_batched_eval_tick_by_tick(tmp_path: Path, request: pytest.FixtureRequest,
                                                     policy: str, episodes: int) -> None:
    temp = Path(tempfile.gettempdir())
    if policy == "nearest-frontier":  # (played beside another run: the `side_by_side` fixture)
        before, r, out = request.getfixturevalue("side_by_side")["eq" + policy[:4]]
    else:
        out = tmp_path / "run.json"
        before = set(temp.glob(f"swarm-eq{policy[:4]}-*"))
        r = swarm("run", "--headless", "--robots", "4", "--policy", policy, "--episodes",
                  str(episodes), "--seed", "11", "--run-id", "eq" + policy[:4], "--json",
                  str(out))
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    assert "logs" not in res and set(temp.glob(f"swarm-eq{policy[:4]}-*")) == before  # tidied
    cfg = WorldConfig(n_robots=4)
    ev = evaluate(cfg, make_policy(policy, cfg), 11, episodes, record_actions=True)
    assert np.array_equal(np.array(res["actions"]), np.stack(ev.actions, 1))
    summ = ev.summary(cfg)
    for key in ("elratio_mean", "reward_mean", "collisions_mean", "success_rate"):
        assert res[key] == pytest.approx(summ[key])
    assert res["timeouts"] == 0 and res["messages"]["bad"] == 0
    assert res["ticks_per_s"] > 0 and res["result_message_lost"] is False
    assert res["command"].startswith("swarm run --headless") and res["checkpoint"] is None
    assert res["world"]["n_robots"] == 4 and res["provenance"]["python"]  # what made it
    lines = [json.loads(line) for line in r.stdout.splitlines() if line.startswith("{")]
    assert sum("status" in rec for rec in lines) == episodes * cfg.horizon
    assert "result" in lines[-1]


@pytest.mark.procs
def test_run_json_records_the_run_config_that_made_it(tmp_path: Path) -> None:
    """UA 75: `[run] greedy = false` and `tick_timeout = 0.3` changed the run but its JSON held
    neither; it now holds the whole resolved `[run]` config as `run`."""
    cfg = tmp_path / "r.toml"
    cfg.write_text('[world]\nn_robots = 2\nhorizon = 4\n[run]\npolicy = "nearest-frontier"\n'
                   'episodes = 1\ngreedy = false\ntick_timeout = 0.3\nwatchdog = 30\n')
    out = tmp_path / "run.json"
    r = swarm("run", "--headless", "--config", str(cfg), "--run-id", "runcfg", "--json", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    run = json.loads(out.read_text())["run"]
    assert (run["greedy"], run["tick_timeout"], run["watchdog"]) == (False, 0.3, 30.0), run
    assert (run["policy"], run["episodes"], run["checkpoint"]) == ("nearest-frontier", 1, None)


@pytest.fixture(scope="module")
def range_logdir_run(tmp_path_factory: pytest.TempPathFactory
                     ) -> tuple[subprocess.CompletedProcess[str], Path, set[Path]]:
    """One run for two tests (one run instead of two): 3 random robots, one episode, with
    `--comm-range 0` (the range test) and `--log-dir` (the temp folder test). Its process, its
    folder (run.json, logs/) and its run id's temp folders before it started."""
    tmp, temp = tmp_path_factory.mktemp("logdir1"), Path(tempfile.gettempdir())
    before = set(temp.glob("swarm-logdir1-*"))
    r = swarm("run", "--headless", "--robots", "3", "--policy", "random", "--episodes", "1",
              "--comm-range", "0", "--run-id", "logdir1", "--log-dir", str(tmp / "logs"),
              "--json", str(tmp / "run.json"))
    return r, tmp, before


@pytest.mark.procs
def test_a_run_with_a_log_dir_leaves_nothing_in_the_temp_folder(
        range_logdir_run: tuple[subprocess.CompletedProcess[str], Path, set[Path]]) -> None:
    """--log-dir: the logs and the run's spec are in the log dir; the temp folder the run
    made for its children (the spec, the world's result file) is gone after a clean run."""
    r, tmp, before = range_logdir_run
    temp, logs = Path(tempfile.gettempdir()), tmp / "logs"
    assert r.returncode == 0, r.stderr
    assert set(temp.glob("swarm-logdir1-*")) == before
    spec = json.loads((logs / "spec.json").read_text())
    assert spec["run"]["run_id"] == "logdir1" and (logs / "world.log").is_file()


@pytest.mark.procs
def test_range_limited_delivery_out_of_range_hears_nothing(
        range_logdir_run: tuple[subprocess.CompletedProcess[str], Path, set[Path]]) -> None:
    """comm_range 0: every bundle holds exactly the receiver's own message."""
    r, tmp, _ = range_logdir_run
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp / "run.json").read_text())
    m = res["messages"]
    assert m["traj_delivered"] == m["traj_in"] == 3 * 30
    assert m["out_of_range"] > 0


@pytest.mark.procs
def test_malformed_payloads_are_dropped_and_counted(tmp_path: Path) -> None:
    out = tmp_path / "run.json"
    run_id = "badmsg"
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "3", "--policy",
         "random", "--episodes", "4", "--run-id", run_id, "--json", str(out), "--tick-timeout",
         "1", "--pace", "40"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    keys = Keys(run_id)
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()  # the first tick's status: the swarm is up
        assert "status" in first, proc.stderr.read() if proc.stderr else ""
        # Join as a plain Zenoh client by the world's port, found from the supervisor's child.
        hub = _hub_of(run_id)
        with zenoh.open(ZenohOptions(connect=[hub]).to_config()) as s:
            time.sleep(0.3)
            junk = [b"", b"\xc1", b"\x93\x01\x01\x01", b"\x92\x01\x01", b"not msgpack at all"]
            targets = [keys.traj(0), keys.hidden(1), keys.action(2), keys.control, keys.obs(0),
                       keys.inbox(1), keys.inbox_hidden(2)]
            for key in targets:
                for payload in junk:
                    s.put(key, payload)
        proc.communicate(timeout=60)  # drain stdout: a full pipe would stall the supervisor
        assert proc.returncode == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    res = json.loads(out.read_text())
    assert res["completed"] == 4
    assert res["messages"]["bad"] >= 3 * len(junk)  # every junk payload on a world key
    assert sum(r["bad"] for r in res["robot_status"].values()) > 0
    assert res["robots_lost"] == 0 and res["robot_crashes"] == 0


def _hub_of(run_id: str) -> str:
    for pid in run_procs(run_id):
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        if b"robot" in cmd and b"--connect" in cmd:
            return cmd[cmd.index(b"--connect") + 1].decode()
    raise AssertionError("no robot process found")


@pytest.fixture(scope="module")
def killed_robot(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, str, dict]:
    """An unpaced 6-episode run of 3 robots whose robot 2 is SIGKILLed by nobody's plan once it
    plays, for two tests (one run instead of two): its exit status, stderr and result."""
    return upset_run(tmp_path_factory.mktemp("killone"), "killone", 3, b"--id\x002\x00",
                     lambda pid: os.kill(pid, signal.SIGKILL), episodes=6, pace=None)


def test_killed_robot_is_noticed_and_mission_goes_on(killed_robot: tuple[int, str, dict]
                                                     ) -> None:
    code, err, res = killed_robot
    assert code == 0, err[-2000:]
    assert res["completed"] == 6
    assert res["robots_lost"] == 1
    assert res["robot_crashes"] == 1


@pytest.mark.procs
def test_ctrl_c_leaves_no_process_behind() -> None:
    run_id = "ctrlc"
    # started with SIGINT ignored, as a shell without job control starts `swarm run ... &`:
    # the CLI takes Ctrl-C back (swarm.cli.main), or the run would be deaf to it
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "3", "--policy",
         "random", "--episodes", "1000", "--run-id", run_id],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    assert proc.stdout is not None
    proc.stdout.readline()
    assert len(run_procs(run_id)) >= 4  # supervisor, world, 3 robots
    proc.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    proc.communicate(timeout=10)
    while run_procs(run_id) and time.monotonic() - t0 < 3.0:
        time.sleep(0.05)
    assert run_procs(run_id) == []
    assert time.monotonic() - t0 < 3.5


_EARLY_SIGINT = """
import importlib.abc, os, signal, sys
signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a shell without job control starts `cmd &`


class Interrupt(importlib.abc.MetaPathFinder):  # Ctrl-C while the command modules load
    def find_spec(self, name, path=None, target=None):
        if name == "swarm.cli.batch":
            os.kill(os.getpid(), signal.SIGINT)
        return None


sys.meta_path.insert(0, Interrupt())
from swarm.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.procs
def test_a_ctrl_c_while_the_cli_loads_is_not_lost() -> None:
    """A SIGINT that lands while `swarm` is still importing its command modules, in a process
    started with SIGINT ignored: once lost for good (the run went on to its end); now the run
    never starts: one line, exit 130."""
    r = subprocess.run([sys.executable, "-c", _EARLY_SIGINT, "run", "--headless", "--robots", "2",
                        "--policy", "random", "--episodes", "1000", "--run-id", "earlyint"],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 130 and r.stderr.strip() == "swarm: interrupted", r.stderr[-2000:]
    assert run_procs("earlyint") == []


@pytest.mark.procs
def test_two_runs_side_by_side_do_not_cross_talk(
        side_by_side: dict[str, tuple[set[Path], subprocess.CompletedProcess[str], Path]]
) -> None:
    # (the two runs of the `side_by_side` fixture, played at once)
    for run_id, robots, seed in (("eqnear", 4, 11), ("sideB", 3, 4)):
        _, r, path = side_by_side[run_id]
        assert r.returncode == 0, r.stderr[-2000:]
        res = json.loads(path.read_text())
        cfg = WorldConfig(n_robots=robots)
        ev = evaluate(cfg, make_policy("nearest-frontier", cfg), seed, 2, record_actions=True)
        assert np.array_equal(np.array(res["actions"]), np.stack(ev.actions, 1))
        assert res["messages"]["bad"] == 0 and res["messages"]["late"] == 0


@pytest.mark.procs
def test_manual_start_and_robots_exit_when_world_dies(tmp_path: Path) -> None:
    """`swarm world` + `swarm robot` by hand (the README's two-terminal start): a robot that
    never came is named in the result (and on stderr); a second process with a robot's or the
    world's id is refused in one line; kill the world."""
    from swarm.net.zconfig import free_port

    hub = f"tcp/127.0.0.1:{free_port()}"
    out, conf = tmp_path / "world.json", tmp_path / "run.toml"
    conf.write_text("[run]\nstart_timeout = 3.0\n")
    world = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "world", "--run-id", "manual", "--robots", "3",
         "--policy", "random", "--episodes", "1", "--listen", hub, "--json", str(out),
         "--config", str(conf)], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    robots = [subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "robot", "--id", str(i), "--run-id", "manual",
         "--connect", hub], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        for i in range(2)]
    try:
        assert world.wait(timeout=60) == 0
        res = json.loads(out.read_text())
        assert res["completed"] == 1 and res["timeouts"] == 0 and res["never_joined"] == [2]
        assert res["run"]["start_timeout"] == 3.0 and res["run"]["greedy"] is True  # (as run's)
        assert b"robots [2] not alive" in world.stderr.read()  # type: ignore[union-attr]
        for r in robots:  # the world is gone after its run's end: robots leave by themselves
            assert r.wait(timeout=10) == 0
        # Second round: SIGKILL a world mid-run; its robots must still exit on their own.
        world = subprocess.Popen(
            [sys.executable, "-m", "swarm.cli", "world", "--run-id", "manual2", "--robots", "2",
             "--policy", "random", "--episodes", "100000", "--listen", hub],
            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        robots = [subprocess.Popen(
            [sys.executable, "-m", "swarm.cli", "robot", "--id", str(i), "--run-id", "manual2",
             "--connect", hub], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for i in range(2)]
        time.sleep(3.0)
        dups = [subprocess.Popen([sys.executable, "-m", "swarm.cli", *args, "--run-id", "manual2",
                                  "--connect", hub], cwd=ROOT, stderr=subprocess.PIPE, text=True)
                for args in (["robot", "--id", "1"], ["world", "--robots", "2"])]
        for d, who in zip(dups, ("robot 1 of run manual2", "a world of run manual2"), strict=True):
            err = d.communicate(timeout=60)[1]
            assert d.returncode == 2 and f"{who} is running already" in err, err
            assert err.strip().splitlines()[-1].startswith("swarm: error:"), err  # one line
        assert all(r.poll() is None for r in robots)
        world.kill()
        for r in robots:  # (3: the world left before the run's end)
            assert r.wait(timeout=10) == 3
    finally:
        for p in [world, *robots]:
            if p.poll() is None:
                p.kill()


def test_a_world_by_hand_stopped_by_a_control_record_exits_3(tmp_path: Path) -> None:
    """As `swarm run` does: a stop on the control key ends the world before its last episode,
    `stopped` in its result and exit status 3 (it exited 0). The stop says why: a supervisor's
    on Ctrl-C is "interrupt" (its result said "control", an operator's stop, in a recording)."""
    from swarm.net.messages import K_CONTROL, pack_record
    from swarm.net.zconfig import free_port

    hub, out = f"tcp/127.0.0.1:{free_port()}", tmp_path / "w.json"
    procs = [subprocess.Popen([sys.executable, "-m", "swarm.cli", *args, "--run-id", "wstop"],
                              cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
             for args in (["world", "--robots", "1", "--episodes", "1000", "--pace", "50",
                           "--listen", hub, "--json", str(out)], ["robot", "--id", "0",
                                                                  "--connect", hub])]
    try:
        with zenoh.open(ZenohOptions(connect=[hub]).to_config()) as s:
            playing = threading.Event()
            sub = s.declare_subscriber(Keys("wstop").status, lambda _: playing.set())
            assert playing.wait(60)  # a tick was played: both are up
            s.put(Keys("wstop").control, pack_record(K_CONTROL, {"stop": True,
                                                                 "why": "interrupt"}))
            sub.undeclare()
            assert procs[0].wait(timeout=30) == 3
        res = json.loads(out.read_text())
        assert res["stopped"] == "interrupt" and res["completed"] < 1000
        n = res["completed"]  # the keys of every result, None where no episode completed
        assert res["robots"] == 1 and res["episodes"] == n and res["seed"] == 0
        assert (res["elratio_mean"] is None) == (n == 0) and "success_rate" in res
        assert procs[1].wait(timeout=10) == 0
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()


def test_restart_crashed_brings_a_killed_robot_back(tmp_path: Path) -> None:
    res = _run_killing_robot("restart1", 2, tmp_path / "run.json", "--episodes", "12",
                             "--restart-crashed", "--pace", "50")
    assert res["completed"] == 12
    assert res["robot_crashes"] == 1 and res["robot_restarts"] == 1
    assert res["robots_lost"] == 0  # it was back (alive) by the end
    # virtual time waits for every robot it observed; the one that came back mid-tick joined at
    # the next tick, so no tick waited for its action until the watchdog
    assert res["timeouts"] == 0
    last_ep = np.array(res["actions"][-1])
    assert (last_ep[:, 2] != 0).any()  # and acting again


@pytest.mark.procs
def test_bench_swarm_prints_and_writes_figures(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    r = swarm("bench", "swarm", "--robots", "2,3", "--policy", "nearest-frontier,random",
              "--episodes", "1", "--repeats", "2", "--json", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    assert "ticks/s" in r.stdout and "Medians over 2 interleaved rounds" in r.stdout
    result = json.loads(out.read_text())
    rows = result["rows"]
    # rounds interleave: every (policy, team size) once per round
    assert [(row["round"], row["policy"], row["robots"]) for row in rows] == [
        (k, p, n) for k in (0, 1) for p in ("nearest-frontier", "random") for n in (2, 3)]
    speed = {(row["round"], row["policy"], row["robots"]): row["ticks_per_s"] for row in rows}
    for m in result["summary"]:
        mine = [speed[(k, m["policy"], m["robots"])] for k in (0, 1)]
        ratios = [speed[(k, m["policy"], m["robots"])] / speed[(k, "nearest-frontier",
                                                                m["robots"])] for k in (0, 1)]
        assert m["ticks_per_s"] == mine and m["vs_first"] == pytest.approx(ratios)
        assert m["ticks_per_s_median"] == pytest.approx(sum(mine) / 2)
        assert m["vs_first_median"] == pytest.approx(sum(ratios) / 2)
    for row in rows:
        assert row["ticks_per_s"] > 0 and row["startup_s"] > 0
        assert 5 < row["rss_mb_per_robot"] < 250  # a frontier robot never imports torch
        assert row["pss_mb_world"] is not None and 0 < row["pss_mb_world"] <= row["rss_mb_world"]


@pytest.mark.procs
@pytest.mark.parametrize("sample", [False, True])
def test_commattn_swarm_matches_batched_eval_tick_by_tick(tmp_path: Path, sample: bool) -> None:
    """The shipped CommAttn checkpoint over the predecessor chain of hidden-state messages."""
    ckpt = str(ROOT / "checkpoints" / "commattn.pt")
    out = tmp_path / "run.json"
    args = ["run", "--headless", "--robots", "10", "--policy", "commattn", "--checkpoint", ckpt,
            "--episodes", "1", "--seed", "21", "--run-id", f"eqca{int(sample)}", "--json", str(out)]
    r = swarm(*args, *(["--sample"] if sample else []), timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    cfg = WorldConfig()
    ev = evaluate(cfg, make_policy("commattn", cfg, checkpoint=ckpt), 21, 1,
                  record_actions=True, greedy=not sample)
    assert np.array_equal(np.array(res["actions"]), np.stack(ev.actions, 1))
    assert res["messages"]["hidden_delivered"] > 0 and res["timeouts"] == 0
    assert res["fast_lane_ticks"] == res["ticks"] and res["messages"]["bad"] == 0  # no fault
    assert res["elratio_mean"] == pytest.approx(ev.summary(cfg)["elratio_mean"])
    # where the chain's time goes: a message k hops down waits for the k before it
    depth = res["chain_ms_by_depth"]
    assert len(depth) >= 3 and min(depth) > 0 and depth[-1] > depth[0]


def _run_killing_robot(run_id: str, robot: int, out: Path, *extra: str,
                       timeout: float = 120) -> dict:
    """`swarm run` that SIGKILLs robot `robot` after the first tick; returns the result JSON."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "3", "--policy",
         "nearest-frontier", "--run-id", run_id, "--json", str(out), *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()
        victim = [p for p in run_procs(run_id)
                  if f"--id\x00{robot}\x00".encode() in Path(f"/proc/{p}/cmdline").read_bytes()]
        assert victim
        os.kill(victim[0], signal.SIGKILL)
        proc.communicate(timeout=timeout)  # drain stdout: a full pipe would stall the supervisor
        assert proc.returncode == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    return json.loads(out.read_text())


@pytest.mark.procs
def test_a_training_world_waits_for_its_learner(tmp_path: Path) -> None:
    """A world of a training run started by hand takes no tick before its learner is up: with
    none within start_timeout it ends with one line (its robots leave by themselves)."""
    from swarm.net.zconfig import free_port

    hub = f"tcp/127.0.0.1:{free_port()}"
    (tmp_path / "c.toml").write_text("[run]\ntrain = true\nstart_timeout = 2\n")
    world = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "world", "--run-id", "nolearner", "--robots", "1",
         "--policy", "commattn", "--episodes", "1", "--listen", hub, "--config",
         str(tmp_path / "c.toml")], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        text=True)
    robot = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "robot", "--id", "0", "--run-id", "nolearner",
         "--connect", hub], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _, err = world.communicate(timeout=60)
        assert world.returncode == 1 and "no learner came alive within 2 s" in err, err
        assert err.strip().splitlines()[-1].startswith("swarm: error:")
        assert robot.wait(timeout=30) == 3  # its world left before the run's end
    finally:
        for p in (world, robot):
            if p.poll() is None:
                p.kill()


def test_a_world_that_fails_is_reported_with_its_own_error(tmp_path: Path) -> None:
    """When the world ends without a result, the supervisor's one error names the world's own
    last exception (from its log), not only the exit code."""
    from swarm.common.spawn import last_error

    log = tmp_path / "world.log"
    log.write_text("Traceback (most recent call last):\n  File \"x.py\", line 1, in <module>\n"
                   "    raise RuntimeError(...)\nRuntimeError: no robot came alive within 15 s\n")
    assert last_error(log) == "RuntimeError: no robot came alive within 15 s"
    log.write_text("swarm: error: [Errno 30] Read-only file system: '/x/l'\n")  # a CLI error
    assert last_error(log) == "[Errno 30] Read-only file system: '/x/l'"
    log.write_text("a warning\n")
    assert last_error(log) == "" and last_error(tmp_path / "missing.log") == ""


@pytest.mark.procs
@pytest.mark.parametrize("name", ["commnet", "vain", "bicnet"])
@pytest.mark.parametrize("sample", [False, True])
def test_every_learned_policy_swarm_matches_batched_eval(tmp_path: Path, name: str,
                                                          sample: bool) -> None:
    """The shipped checkpoints of the other learned policies, acted in numpy by torch-free
    robot processes, against the batched evaluator: the same actions, greedy and sampled."""
    out = tmp_path / "run.json"
    r = swarm("run", "--headless", "--robots", "4", "--policy", name, "--episodes", "1",
              "--seed", "8", "--run-id", f"eq{name}{int(sample)}", "--json", str(out),
              *(["--sample"] if sample else []), timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    cfg = WorldConfig(n_robots=4)
    ev = evaluate(cfg, make_policy(name, cfg, checkpoint=str(ROOT / "checkpoints" / f"{name}.pt")),
                  8, 1, record_actions=True, greedy=not sample)
    assert np.array_equal(np.array(res["actions"]), np.stack(ev.actions, 1))
    assert res["rss_mb_per_robot"] < 120  # numpy, no torch


@pytest.mark.procs
def test_headless_output_into_a_closed_pipe_stops_the_run_quietly_and_tidily() -> None:
    """`swarm run --headless | head -1`: the reader goes away. It printed a warning per status
    record ("dropped a status record ... Broken pipe"), ran to the end and failed with exit 1;
    now it stops as on Ctrl-C (every process; exit 141, as a shell reports a SIGPIPE; one line
    saying why, not "interrupted"), and an interrupted run's temp folder goes when its logs say
    nothing (it was left behind, named nowhere)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "2", "--episodes",
         "50", "--policy", "random", "--pace", "20", "--run-id", "pipeclosed"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stderr is not None
        assert "status" in proc.stdout.readline()
        proc.stdout.close()
        assert proc.wait(timeout=60) == 141
        err = proc.stderr.read()
        assert "Broken pipe" not in err and len(err.strip().splitlines()) == 1, err
        assert err.startswith("swarm: stdout was closed (its reader went away)"), err
    finally:
        if proc.poll() is None:
            proc.kill()
    assert run_procs("pipeclosed") == []
    assert list(Path(tempfile.gettempdir()).glob("swarm-pipeclosed-*")) == []


PLUGIN = CYCLIC_PLUGIN + '''

class Nan(Cyclic):
    """A buggy one: NaN moves."""

    def act(self, view, greedy=True):
        return np.full(view.receivers.shape, np.nan)


class Boom(ChainPlan):
    """A buggy chained one: robot 1 fails from tick 1 on."""

    name = "boom"

    def act_with_chain(self, view, *args, **kwargs):
        if view.tick >= 1 and receiver_index(view)[1] == 1:
            raise RuntimeError("boom")
        return super().act_with_chain(view, *args, **kwargs)
'''


def install_plugin(tmp_path: Path) -> dict[str, str]:
    """The package of PLUGIN on a path of its own, declared by its entry points; the
    environment that makes it importable."""
    (tmp_path / "cyclic_plugin.py").write_text(PLUGIN)
    info = tmp_path / "cyclic_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: cyclic-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[commattn_swarm.policies]\n"
                                           "cyclic = cyclic_plugin:Cyclic\nbroken = nocolon\n"
                                           "nan = cyclic_plugin:Nan\nsyntax = bad_plugin:X\n"
                                           "boom = cyclic_plugin:Boom\n")
    (tmp_path / "bad_plugin.py").write_text("def (:\n")
    return {"PYTHONPATH": str(tmp_path)}


@pytest.mark.procs
def test_a_policy_of_another_package_runs_in_eval_and_in_a_swarm(tmp_path: Path) -> None:
    """A package that declares an entry point in the `commattn_swarm.policies` group (README,
    "Building on it: your policy, your analysis") adds its policy to every command, robot
    processes included, without touching this repository; a malformed entry is skipped with a
    warning."""
    env = install_plugin(tmp_path)
    ev, run = tmp_path / "eval.json", tmp_path / "run.json"
    r = swarm("eval", "--policy", "cyclic,random", "--robots", "3", "--episodes", "2", "--seed",
              "4", "--json", str(ev), env=env)
    assert r.returncode == 0, r.stderr
    assert "policy plugin 'broken' = 'nocolon' is not 'module:Class'; skipped" in r.stderr
    r = swarm("run", "--headless", "--policy", "cyclic", "--robots", "3", "--episodes", "2",
              "--seed", "4", "--json", str(run), "--log-dir", str(tmp_path / "logs"), env=env)
    assert r.returncode == 0, r.stderr
    # said once a command, not again in each child's log (a swarm of hundreds had hundreds)
    assert r.stderr.count("is not 'module:Class'") == 1, r.stderr
    logs = sorted((tmp_path / "logs").glob("*.log"))
    assert logs and not any("module:Class" in p.read_text() for p in logs)
    batched = json.loads(ev.read_text())["results"][0]
    swarmed = json.loads(run.read_text())
    assert batched["policy"] == swarmed["policy"] == "cyclic"
    for key in ("elratio_mean", "reward_mean", "collisions_mean"):
        assert swarmed[key] == pytest.approx(batched[key])
    assert np.array_equal(np.array(swarmed["actions"])[0, 0], [0, 1, 2])  # tick 0: robot i -> i
    for name, why in (("nan", "policy nan: actions must be integers in 0..8, got float64"),
                      ("syntax", "policy plugin 'syntax' (bad_plugin:X) does not import: "
                                 "SyntaxError")):  # a plugin's bug: one line, not a traceback
        r = swarm("eval", "--policy", name, "--robots", "3", "--episodes", "1", env=env)
        assert r.returncode == 2 and why in r.stderr and "Traceback" not in r.stderr, r.stderr
    # on the swarm, a robot whose policy fails stays in place and says so; nobody waits for it
    # (each tick waited out the 10 s watchdog, and the run ended with exit 0 and no word)
    r = swarm("run", "--headless", "--policy", "nan", "--robots", "3", "--episodes", "1",
              "--horizon", "4", "--json", str(run), env=env)
    assert r.returncode == 0 and "robot 1 could not decide on 4 ticks" in r.stderr, r.stderr
    res = json.loads(run.read_text())
    assert res["timeouts"] == 0 and not np.array(res["actions"]).any()
    r = swarm("eval", "--policy", "cyclic", "--episodes", "1")  # not installed: unknown
    assert r.returncode == 2 and "unknown policy 'cyclic'" in r.stderr


@pytest.mark.procs
@pytest.mark.parametrize("fault", [[], ["--loss", "0.01"], ["--delivery", "direct"]],
                         ids=["fast-lane", "radio", "direct"])
def test_a_chained_robot_that_cannot_decide_says_so_to_its_successor(tmp_path: Path,
                                                                    fault: list[str]) -> None:
    """A chained robot whose policy fails sends an empty hidden state: its successor decodes
    without it at once, and the world does not wait for it. Before, each such tick waited out
    the watchdog (here 600 s, so the run would outlast the test's timeout)."""
    env, run = install_plugin(tmp_path), tmp_path / "run.json"
    r = swarm("run", "--headless", "--policy", "boom", "--robots", "3", "--episodes", "1",
              "--horizon", "4", "--seed", "2", "--watchdog", "600", "--json", str(run), *fault,
              env=env, timeout=120)
    assert r.returncode == 0 and "robot 1 could not decide on 3 ticks" in r.stderr, r.stderr
    res = json.loads(run.read_text())
    assert res["timeouts"] == 0 and not np.array(res["actions"])[0, 1:, 1].any()
    status = res["robot_status"]
    assert status["2"]["missed_hidden"] >= 3, status  # robot 1 is robot 2's predecessor


def upset_run(tmp_path: Path, run_id: str, robots: int, mark: bytes,
              upset: Callable[[int], None], episodes: int = 3,
              pace: int | None = 10) -> tuple[int, str, dict]:
    """A run of `robots` nearest-frontier robots (3 episodes at 10 ticks/s unless told); once
    it plays, `upset` the pid of its process whose command line holds `mark`. Its exit status,
    stderr and result."""
    out = tmp_path / "r.json"
    proc = swarm_started("run", "--headless", "--robots", str(robots), "--policy",
                         "nearest-frontier", "--episodes", str(episodes), "--seed", "1",
                         "--run-id", run_id, "--json", str(out),
                         *(["--pace", str(pace)] if pace else []))
    try:
        upset(next(p for p in run_procs(run_id)
                   if mark in Path(f"/proc/{p}/cmdline").read_bytes()))
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, err, json.loads(out.read_text())


@pytest.mark.procs
def test_a_robot_killed_by_nobody_is_counted_and_said(killed_robot: tuple[int, str, dict]
                                                      ) -> None:
    """A robot process that dies unplanned (SIGKILL, no error line in its log) is a crash and
    a warning line; the run goes on without it. Before, it was counted silently (exit 0, no
    word): only a death with an error in the log was said. (The `killed_robot` fixture's run.)"""
    code, err, res = killed_robot
    assert code == 0 and "robot 2 failed: killed by SIGKILL" in err, err
    assert res["robot_crashes"] == 1 and res["child_errors"] == {"robot 2": "killed by SIGKILL"}


@pytest.mark.procs
def test_a_robot_stopped_until_after_the_run_is_counted_and_said(tmp_path: Path) -> None:
    """A robot SIGSTOPped by nobody's plan and never resumed: the stall warning and count
    came from the robot itself once it resumed, so this one went unsaid as a stall (at most
    "left the run", once its lease ran out). The run's end finds it stopped: one warning, one
    stall counted, and it is resumed to take the stop (no process left)."""
    code, err, res = upset_run(tmp_path, "sigstopend", 3, b"--id\x002\x00",
                               lambda pid: os.kill(pid, signal.SIGSTOP))
    assert code == 0 and res["completed"] == 3, err
    assert "robot 2 was stopped (SIGSTOP) and not resumed by the run's end" in err, err
    assert "left the run" not in err  # (one line for it)
    assert res["robot_stalls"] == 1 and res["robots_stopped_at_end"] == [2], res["robot_stalls"]
    assert run_procs("sigstopend") == []


@pytest.mark.procs
def test_a_run_id_held_by_a_running_swarm_is_refused(tmp_path: Path) -> None:
    """Two runs of one id on one machine both started, and `swarm fault --run ID` reached only
    the second (UA pass): the second is refused in one line before it spawns anything."""
    proc = swarm_started("run", "--headless", "--robots", "2", "--policy", "nearest-frontier",
                         "--episodes", "20", "--run-id", "twinid", "--pace", "10")
    try:
        r = swarm("run", "--headless", "--robots", "2", "--episodes", "1", "--run-id", "twinid")
        assert r.returncode == 2 and r.stderr == "swarm: error: run id 'twinid' is taken by a " \
            "swarm running on this machine; give another --run-id\n", r.stderr
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=60)


@pytest.mark.procs
def test_robots_that_left_while_the_world_played_on_are_said(tmp_path: Path) -> None:
    """A world stopped past its lease drops every robot's session; its robots take it for the
    run's end and leave, and the world plays the rest without them. That ended with exit 0
    and no word (UA pass); then with a warning line naming them and exit 0, its figures
    averaging episodes nobody played (UA pass 79); now the run fails, whether the world's end
    or the supervisor's 5 s of grace comes first, and says why."""
    def stall(pid: int) -> None:
        os.kill(pid, signal.SIGSTOP)
        time.sleep(4.0)  # (the lease is 1 s)
        os.kill(pid, signal.SIGCONT)

    code, err, res = upset_run(tmp_path, "wstall", 2, b"world\x00--spec", stall)
    line = err.strip().splitlines()[-1]
    assert code == 1 and line.startswith("swarm: error: every robot left the run before its "
                                         "end (robots [0, 1]: the world's token was gone"), err
    assert res["error"] in line, res  # (its figures, averaged over nobody, are not given)
