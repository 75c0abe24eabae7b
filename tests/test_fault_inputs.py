"""Inputs around faults and runs that used to be silently dropped or overridden: each is now
refused in one line before anything runs, or acted on and said; live fault changes queue, each
at its own tick; a control record is checked whole, and a run stopped by one says so."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import pytest
import zenoh
from conftest import ROOT, swarm, swarm_here

from swarm.common.spawn import lookup_run
from swarm.net.faults.control import MAX_PENDING, FaultSchedule, check_control
from swarm.net.keys import Keys
from swarm.net.messages import K_CONTROL, pack_record
from swarm.net.zconfig import ZenohOptions
from world.config import ConfigError


def _refused(*args: str, why: str) -> None:
    r = swarm(*args, timeout=60)
    assert r.returncode == 2, (args, r.returncode, r.stderr[-800:])
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("swarm: error: ") and why in lines[0], lines


# ------------------------------------------------------------------ refused before a spawn


def test_clock_settings_given_to_the_other_clock_are_refused() -> None:
    """--compute-ms models compute time on the virtual clock; --watchdog is a virtual-clock
    setting; --netns runs on the real clock: each given with the other clock is one line."""
    _refused("run", "--headless", "--compute-ms", "5", "--clock", "real", why="--compute-ms")
    _refused("world", "--compute-ms", "5", "--clock", "real", why="--compute-ms")
    _refused("run", "--headless", "--netns", "--clock", "virtual", why="drop --clock virtual")
    _refused("run", "--headless", "--clock", "real", "--watchdog", "5", why="--watchdog")


def test_training_flags_need_train_and_make_no_folder(tmp_path: Path) -> None:
    out = tmp_path / "learner"
    for flags in (["--train-batch", "4"], ["--rollout-loss", "0.2"], ["--learner-out", str(out)],
                  ["--train-algo", "ppo"], ["--train-ppo-epochs", "2"]):
        _refused("run", "--headless", *flags, why=f"{flags[0]} is a training setting")
    assert not out.exists()


def test_a_learner_folder_holding_a_learner_is_refused_before_any_spawn(tmp_path: Path) -> None:
    out = tmp_path / "learner"
    out.mkdir()
    (out / "checkpoint.pt").write_bytes(b"a learner's checkpoint")
    logs = tmp_path / "logs"
    _refused("run", "--headless", "--train", "--robots", "2", "--episodes", "1",
             "--learner-out", str(out), "--log-dir", str(logs), why="already holds a learner")
    assert not logs.exists()  # refused before the supervisor made anything


def test_a_process_fault_beyond_the_runs_last_tick_is_refused() -> None:
    _refused("run", "--headless", "--episodes", "1", "--crash", "1@99999",
             why="beyond the run's last tick 29")
    _refused("run", "--headless", "--episodes", "2", "--horizon", "10", "--hang", "0@20",
             why="--hang 0@20 is beyond the run's last tick 19")
    # (a restart at tick 0 of a robot crashed at tick 0 waited out the start timeout: the
    # world waited for a new process the supervisor starts only after the first tick)
    _refused("run", "--headless", "--episodes", "1", "--crash", "1@0", "--restart", "1@0",
             why="--crash 1@0 --restart 1@0: a robot restarted at tick 0")


def test_a_refused_process_fault_is_named_as_the_user_gave_it(tmp_path: Path) -> None:
    """One from the config file is its `[faults]` key, not a flag the user never typed."""
    conf = tmp_path / "f.toml"
    conf.write_text('[faults]\ncrash = ["1@99999"]\n')
    _refused("run", "--headless", "--episodes", "1", "--config", str(conf),
             why='[faults] crash "1@99999" is beyond the run\'s last tick 29')
    conf.write_text('[faults]\nrestart = ["1@0"]\n')
    _refused("run", "--headless", "--episodes", "1", "--config", str(conf), "--crash", "1@0",
             why='--crash 1@0 [faults] restart "1@0": a robot restarted at tick 0')


@pytest.mark.parametrize("value, why", [
    ("nan", "--compute-ms must be a number of milliseconds >= 0, got nan"),
    ("-3", "got -3.0"), ("inf", "got inf"),
    ("1e20", "compute_ms must lie in [0, 3.6e+06], got 1e+20"),
])
def test_a_compute_time_is_said_as_given(value: str, why: str,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """`--compute-ms 1e-05` was refused as "bad duration '1e-05ms'" (the flag's float written
    back as text), NaN as 'nanms': a value the user never typed."""
    r = swarm_here("eval", "--episodes", "1", "--policy", "random", "--compute-ms", value,
                   capsys=capsys)
    assert r.returncode == 2 and why in r.stderr and len(r.stderr.strip().splitlines()) == 1, \
        r.stderr
    from swarm.cli.common import fault_table
    from swarm.net.faults import plan_from_table

    args = argparse.Namespace(compute_ms=1e-05)
    assert plan_from_table(fault_table(args, {})).default.compute_ms == pytest.approx(1e-05)


def test_a_zero_kernel_bandwidth_or_lease_is_refused_not_read_as_the_default() -> None:
    """0 is the fields' "unlimited" and "the usual 1 s": given on the command line it is a
    one-line error before any namespace or process is made, like `--bandwidth 0`."""
    run = ("run", "--headless", "--robots", "4", "--episodes", "1", "--policy",
           "nearest-frontier", "--netns")
    _refused(*run, "--kernel-bandwidth", "0", why="bad --kernel-bandwidth '0'")
    _refused(*run, "--kernel-bandwidth", "0kB/s", why="a cap must be above 0 B/s")
    _refused(*run, "--netns-lease", "0ms", why="bad --netns-lease '0ms'")
    _refused(*run, "--netns-lease", "0", why="a lease must be at least 1 ms")
    _refused(*run, "--netns-lease", "0.4", why="a lease must be at least 1 ms")  # (Zenoh: 0)
    _refused(*run, "--netns-lease", "-1s", why="bad --netns-lease '-1s': a lease must be at "
             "least 1 ms")  # (UA pass 61: "must be >= 0", and then 0 was refused)


@pytest.mark.parametrize("table,why", [
    ("loss = true", "bad loss True: a number is expected"),
    ("burst = false\nbandwidth = \"1kB/s\"", "bad burst False"),
    ("[faults.robot.1]\nloss = true", "bad loss True"),
    ("[faults.link.\"0-0\"]\nloss = 0.5", "bad link '0-0': a robot's link to itself"),
    # a sender's token bucket and compute time are not a link's (they were shown, then ignored)
    ("[faults.link.\"0-1\"]\nbandwidth = \"1B/s\"", "bad link '0-1': bandwidth belong(s) to "
     "the sender"),
    ("[faults.link.\"2-1\"]\ncompute = \"5ms\"\nburst = 9", "bad link '2-1': burst, compute"),
    ("overflow = \"drop\"", "[faults] overflow says what a bandwidth cap does; there is no cap"),
    ("burst = 500\n[faults.robot.1]\nbandwidth = \"none\"", "[faults] burst says what"),
])
def test_nonsense_in_a_faults_table_is_refused(tmp_path: Path, table: str, why: str) -> None:
    """A bool where a number is expected (`loss = true` was loss 1.0) and a link from a robot
    to itself are one-line errors, not a plan."""
    conf = tmp_path / "f.toml"
    conf.write_text(f"[faults]\n{table}\n")
    _refused("run", "--headless", "--robots", "4", "--episodes", "1", "--policy",
             "nearest-frontier", "--config", str(conf), why=why)


def test_a_partition_with_an_empty_group_is_refused() -> None:
    for groups in ("0-1/", "0-1//2-3", "/0"):
        _refused("run", "--headless", "--robots", "4", "--episodes", "1", "--policy",
                 "nearest-frontier", "--partition", groups,
                 why=f"bad partition '{groups}': an empty group")


def test_unknown_robots_are_listed_with_how_many_more_there_are() -> None:
    _refused("run", "--headless", "--robots", "4", "--episodes", "1", "--policy",
             "nearest-frontier", "--partition", "0-9",
             why="faults name robot(s) 4, 5, 6, 7, 8 and 1 more but the team has robots 0..3")


def test_the_help_says_what_a_bare_number_and_a_partial_partition_mean() -> None:
    """What the help says is what the plan does: `--latency 50` is 50 ms, `--partition 0` on
    4 robots is `0/1-3`."""
    from swarm.net.faults import plan_from_table

    text = " ".join(swarm("run", "--help", timeout=60).stdout.split())
    assert "a number alone is ms: 50 is 50ms" in text and "(a number alone is ms)" in text
    assert "the robots left out form one more group (0 on 4 robots is 0/1-3)" in text
    assert plan_from_table({"latency": "50"}) == plan_from_table({"latency": "50 ms"}) == \
        plan_from_table({"latency": "50ms"})
    assert plan_from_table({"partition": "0"}).group_of(4).tolist() == [0, 1, 1, 1] == \
        plan_from_table({"partition": "0/1-3"}).group_of(4).tolist()


def test_robot_wait_must_be_finite_and_positive() -> None:
    for wait in ("nan", "inf", "0"):
        _refused("robot", "--id", "0", "--run-id", "r1", "--wait", wait, why="--wait")


def test_swarm_fault_checks_its_flags_before_the_network() -> None:
    _refused("fault", "--run", "bad id!", "--loss", "0.1", why="bad run id")
    _refused("fault", "--run", "nosuch", "--clear", "--loss", "0.5", why="--clear")
    _refused("fault", "--run", "nosuch", "--at-tick", "5", "--crash", "1", why="--at-tick")


# ------------------------------------------------------------- control records, in process


def test_a_control_record_is_checked_whole_before_any_field_acts() -> None:
    for rec in ({"stop": "no"}, {"stop": 1}, {"stop": False},
                {"stop": True, "faults_table": {"loss": 7}},
                {"stop": True, "process": ["crash:9"]},
                {"stop": True, "at_tick": True, "faults_table": {}},
                {"stop": True, "replace": "yes", "faults_table": {}},
                {"stop": True, "bogus": 1}, {"process": ["bogus:1"]},
                {"stop": True, "why": "control"}, {"why": "interrupt"}):  # (why: only Ctrl-C's)
        with pytest.raises(ConfigError):
            check_control(rec, 0, 3)
    c = check_control({"stop": True, "faults_table": {"loss": "0.5", "crash": ["1@3"]},
                       "at_tick": 50, "process": ["restart:1@5"]}, 0, 3)
    assert c.stop and c.table == {"loss": "0.5"} and c.at_tick == 50
    assert [(p.kind, p.robot, p.tick) for p in c.process] == [("restart", 1, 5)]
    assert c.why == "control" and check_control({"stop": True, "why": "interrupt"}, 0, 3).why \
        == "interrupt"


def test_queued_changes_apply_each_at_its_own_tick_onto_the_table_in_force() -> None:
    s = FaultSchedule({"jitter": "5ms"}, 0, 3)
    s.add(check_control({"faults_table": {"loss": 0.5}, "at_tick": 50}, 0, 3), 10)
    s.add(check_control({"faults_table": {"latency": "50ms"}, "at_tick": 70}, 0, 3), 20)
    assert all(s.due(t) is None for t in range(50))
    assert s.due(50).describe() == ["all: latency 0+5ms loss 0.5"]
    assert all(s.due(t) is None for t in range(51, 70))
    assert s.due(70).describe() == ["all: latency 50+5ms loss 0.5"]
    s.add(check_control({"faults_table": {"loss": 0.1}, "at_tick": 60, "replace": True}, 0,
                        3), 80)  # passed already: at the next tick, counted late
    assert s.due(81).describe() == ["all: loss 0.1"]
    assert [(c["tick"], c["at_tick"]) for c in s.summary()["changes"]] == \
        [(50, 50), (70, 70), (81, 60)]
    assert s.summary()["late"] == 1
    for k in range(MAX_PENDING):
        assert s.add(check_control({"faults_table": {"loss": 0.2}, "at_tick": 1000 + k}, 0, 3),
                     90)
    assert not s.add(check_control({"faults_table": {"loss": 0.3}}, 0, 3), 90)
    assert s.summary()["dropped"] == 1 and len(s.summary()["pending"]) == MAX_PENDING


def test_a_replacing_change_keeps_the_runs_fault_seed_unless_it_gives_one() -> None:
    """`swarm run --fault-seed 7` then `swarm fault --replace --loss 0.3` (or `--clear`): the
    replace dropped the seed, and the draws went back to the run's seed (a merge kept it)."""
    s = FaultSchedule({"loss": 0.1, "seed": 7}, 0, 4)
    for k, (table, replace) in enumerate((({"loss": 0.3}, True), ({}, True),
                                          ({"loss": 0.2}, False))):
        s.add(check_control({"faults_table": table, "replace": replace}, 0, 4), k)
        assert s.due(k).seed == 7
    s.add(check_control({"faults_table": {"loss": 0.3, "seed": 9}, "replace": True}, 0, 4), 5)
    assert s.due(5).seed == 9


def test_a_live_overflow_or_burst_with_no_cap_in_force_is_dropped_a_lifted_cap_is_not() -> None:
    """`swarm fault --overflow drop` on a run with no bandwidth cap was applied and changed
    nothing (the command does not know the faults in force; `swarm run` refuses it): the world
    now drops it as unfit, and a change that lifts the cap of a run with an overflow goes."""
    s = FaultSchedule({"loss": 0.1}, 0, 3)
    for table in ({"overflow": "drop"}, {"robot": {"1": {"burst": 2000}}}):
        s.add(check_control({"faults_table": table}, 0, 3), 4)
        assert s.due(4) is None
    assert s.summary()["unfit"] == 2 and s.summary()["applied"] == 0
    s.add(check_control({"faults_table": {"bandwidth": "60B/s", "overflow": "drop"}}, 0, 3), 5)
    assert s.due(5).capped and s.summary()["applied"] == 1
    s.add(check_control({"faults_table": {"overflow": "expire"}}, 0, 3), 6)  # (capped: goes)
    s.add(check_control({"faults_table": {"bandwidth": "none"}}, 0, 3), 7)
    assert s.due(6) is not None and not s.due(7).capped and s.summary()["applied"] == 3


# ------------------------------------------------------------------ the real swarm, live


def _start(run_id: str, out: Path, *args: str) -> tuple[subprocess.Popen[str], list[dict]]:
    """A headless run, once its first status is out; a thread keeps reading its status lines
    (a full pipe would stall the supervisor) into the list returned."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "2", "--policy",
         "random", "--run-id", run_id, "--json", str(out), *args],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    statuses: list[dict] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.startswith('{"status"'):
                statuses.append(json.loads(line)["status"])

    threading.Thread(target=read, daemon=True).start()
    deadline = time.monotonic() + 120
    while not statuses and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert statuses, proc.stderr.read() if proc.stderr else "no status"  # type: ignore
    return proc, statuses


@pytest.mark.procs
def test_two_live_changes_for_later_ticks_both_apply_each_at_its_tick(tmp_path: Path) -> None:
    """Two `swarm fault --at-tick` (loss from T1, latency from T2) both apply, at their own
    ticks (one used to overwrite the other); a tick passed, or beyond the run, is refused with
    nothing sent; a restart of a robot that is up is logged as a no-op; the run's recording
    verifies (`replay --verify` applies the queued changes by the world's rules)."""
    run_id, out, mcap = "fqueue", tmp_path / "r.json", tmp_path / "q.mcap"
    proc, statuses = _start(run_id, out, "--episodes", "3", "--pace", "10", "--restart", "1@3",
                            "--record", str(mcap))
    try:
        t1, t2 = 50, 70
        sent = [subprocess.Popen([sys.executable, "-m", "swarm.cli", "fault", "--run", run_id,
                                  *a], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True)
                for a in (("--loss", "0.5", "--at-tick", str(t1)),
                          ("--latency", "50ms", "--at-tick", str(t2)),
                          ("--loss", "0.9", "--at-tick", "0"),
                          ("--crash", "1@99999"), ("--loss", "0.9", "--at-tick", "90"))]
        res = [(p.wait(timeout=60), *p.communicate()) for p in sent]
        assert [r[0] for r in res] == [0, 0, 2, 2, 2], res
        assert "already" in res[2][2] and "beyond the run's last tick 89" in res[3][2]
        assert "--at-tick 90 is beyond" in res[4][2]
        assert proc.wait(timeout=120) == 0, proc.stderr.read()[-2000:]  # type: ignore
        time.sleep(0.5)  # the reader has the last lines
    finally:
        if proc.poll() is None:
            proc.kill()
    result = json.loads(out.read_text())
    ch = result["fault_changes"]
    assert [(c["tick"], c["at_tick"], c["faults"]) for c in ch["changes"]] == [
        (t1, t1, ["all: loss 0.5"]), (t2, t2, ["all: latency 50+0ms loss 0.5"])]
    assert ch["late"] == ch["dropped"] == 0
    assert result["faults"]["default"]["loss"] == 0.0  # the plan it began with (UA pass: it
    assert result["faults_end"]["default"] == {  # was the last one, under the same key)
        **result["faults"]["default"], "loss": 0.5, "latency_ms": 50.0}
    by_tick = {s["run_tick"]: [f for f in s["faults"] if not f.startswith("restart")]
               for s in statuses}  # status k: tick k - 1 played; its link faults
    assert by_tick[t1] == [] and by_tick[t1 + 1] == ["all: loss 0.5"]
    assert by_tick[t2] == ["all: loss 0.5"] and by_tick[t2 + 1] == ["all: latency 50+0ms loss 0.5"]
    assert result["process_faults"][0].startswith("restart 1@")
    assert result["process_faults"][0].endswith("(not down: nothing done)")
    assert result["robot_restarts"] == 0 and result["messages"]["bad"] == 0
    v = swarm("replay", str(mcap), "--verify", timeout=120)
    assert v.returncode == 0 and "every one as recorded" in v.stdout, v.stdout + v.stderr


@pytest.mark.procs
def test_only_a_checked_stop_ends_a_run_and_the_run_says_so(tmp_path: Path) -> None:
    """`stop: "no"`, or a stop beside a bad faults table, is dropped and counted; a real stop
    ends the run with `stopped: control` in the result, a note on stderr and exit 3."""
    run_id, out = "fstop", tmp_path / "r.json"
    proc, _ = _start(run_id, out, "--episodes", "50", "--pace", "10")
    keys = Keys(run_id)
    try:
        conf = ZenohOptions(mode="client", connect=[lookup_run(run_id)]).to_config()
        with zenoh.open(conf) as session:
            time.sleep(0.5)
            session.put(keys.control, msgpack.packb([1, K_CONTROL, {"stop": "no"}]))
            session.put(keys.control, pack_record(K_CONTROL, {"stop": True,
                                                              "faults_table": {"loss": 7}}))
            for k in range(MAX_PENDING + 3):  # 3 more well-formed changes than a run holds
                session.put(keys.control, pack_record(K_CONTROL, {
                    "faults_table": {"loss": 0.01}, "at_tick": 10**6 + k}))
                session.put(keys.control, pack_record(K_CONTROL, {  # (the supervisor's queue)
                    "process": [f"hang:1@{10**6 + k}"]}))
            time.sleep(2.0)
            assert proc.poll() is None  # neither stopped it
            session.put(keys.control, pack_record(K_CONTROL, {"stop": True}))
            proc.wait(timeout=60)
            err = proc.stderr.read()  # type: ignore[union-attr]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 3, err[-2000:]
    assert f"swarm: run {run_id} was stopped by a control message" in err
    res = json.loads(out.read_text())
    assert res["stopped"] == "control" and res["completed"] < 50
    assert res["messages"]["bad_by_key"][keys.control] == 2
    assert res["supervisor_bad"] == 2  # (the supervisor checks the whole record too)
    # each message in one counter: the 3 changes the queue had no room for are
    # fault_changes.dropped, not bad as well (they were counted in both)
    assert res["fault_changes"]["dropped"] == 3 and len(res["fault_changes"]["pending"]) == \
        MAX_PENDING
    assert res["process_faults_dropped"] == 3 and len(res["process_faults_pending"]) == \
        MAX_PENDING
    # said by the run too (UA pass: only the world's log, which a clean run removes, said it)
    assert f"swarm: warning: 3 live link-fault change(s) dropped (more than {MAX_PENDING} were " \
        "waiting)" in err, err


def test_run_help_names_the_exit_status_of_a_stopped_run() -> None:
    r = swarm("run", "--help")
    assert r.returncode == 0 and "3 stopped before every episode" in " ".join(r.stdout.split())


def test_a_failed_namespace_command_names_its_cause_not_ip_batchs_last_line() -> None:
    """UA pass 61: as root without CAP_NET_ADMIN, `ip -batch` says why ("mount --make-shared
    /run/netns failed: Operation not permitted") and then "Command failed -:1"; the error kept
    only that last line."""
    from swarm.net.kernel.netns import _run

    script = ("echo 'mount --make-shared /run/netns failed: Operation not permitted' >&2; "
              "echo 'Command failed -:1' >&2; exit 2")
    with pytest.raises(ConfigError) as exc:
        _run(["sh", "-c", script])
    assert str(exc.value) == (
        f"netns: `sh -c {script}` failed: mount --make-shared /run/netns failed: Operation not "
        "permitted (root without CAP_NET_ADMIN and CAP_SYS_ADMIN, e.g. an unprivileged "
        "container)")


def test_world_help_names_the_exit_status_of_a_world_no_robot_joined() -> None:
    """`swarm world --start-timeout 2` with no robot says "no robot came alive within 2 s" and
    exits 1, which its help did not list (UA pass)."""
    r = swarm("world", "--help")
    assert r.returncode == 0 and "1 the run could not go on (no robot" in " ".join(r.stdout.split())
