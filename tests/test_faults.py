"""Fault models: parsing, seeded statistics, the radio's decisions, and the real swarm under
faults."""

from __future__ import annotations

import json
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
from swarm.net.faults import (
    FaultPlan,
    LinkFault,
    delivery_mask,
    parse_duration_ms,
    parse_partition,
    parse_process,
    parse_rate,
    plan_from_table,
)
from swarm.net.radio import Radio, TokenBucket
from world.config import ConfigError, WorldConfig

# ------------------------------------------------------------------------------- parsing


def test_parsing_of_human_units() -> None:
    assert parse_duration_ms("50ms") == 50 and parse_duration_ms("0.2s") == 200
    assert parse_duration_ms("300") == 300
    assert parse_rate("2kB/s") == 2000 and parse_rate("500B/s") == 500
    assert parse_rate("1MB/s") == 1e6 and parse_rate("2KiB/s") == 2048
    with pytest.raises(ConfigError, match="b would be bits"):  # kilobits to most readers
        parse_rate("2kb/s")
    with pytest.raises(ConfigError, match="must be >= 0"):
        parse_duration_ms("-5ms")
    assert parse_partition("0-4/5-9") == ((0, 1, 2, 3, 4), (5, 6, 7, 8, 9))
    p = parse_process("crash", "3@20")
    assert (p.kind, p.robot, p.tick) == ("crash", 3, 20)
    for bad in (lambda: parse_duration_ms("fast"), lambda: parse_rate("lots"),
                lambda: parse_partition("0-4/3-6"), lambda: parse_process("crash", "x@1"),
                lambda: plan_from_table({"loss": 1.5}), lambda: plan_from_table({"lag": "1ms"})):
        with pytest.raises(ConfigError):
            bad()


@pytest.mark.procs
def test_bad_fault_flag_is_one_line_error() -> None:
    r = swarm("run", "--headless", "--robots", "2", "--loss", "2.0")
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "loss" in r.stderr and "Traceback" not in r.stderr


# ------------------------------------------------------------------------------- statistics


def test_zero_plan_delivers_everything() -> None:
    ok = delivery_mask(FaultPlan(), np.arange(5), 3, 6)
    assert ok.all()
    assert FaultPlan(default=LinkFault(loss=0.0, latency_ms=0.0)).zero


def test_loss_rate_matches_setting_and_is_seeded() -> None:
    plan = plan_from_table({"loss": 0.3, "seed": 7})
    masks = np.stack([delivery_mask(plan, np.arange(50), t, 10) for t in range(30)])
    off = ~np.eye(10, dtype=bool)
    lost = 1.0 - masks[..., off].mean()
    assert lost == pytest.approx(0.3, abs=0.01)
    assert masks[..., np.eye(10, dtype=bool)].all()  # own message never lost
    again = np.stack([delivery_mask(plan, np.arange(50), t, 10) for t in range(30)])
    assert np.array_equal(masks, again)
    other = plan_from_table({"loss": 0.3, "seed": 8})
    assert not np.array_equal(masks[0], delivery_mask(other, np.arange(50), 0, 10))


def test_partition_cuts_exactly_cross_group_links() -> None:
    plan = plan_from_table({"partition": "0-1/2-4"})
    ok = delivery_mask(plan, np.arange(3), 0, 6)[0]
    grp = np.array([0, 0, 1, 1, 1, 2])  # robot 5 in no group: a group of its own
    assert np.array_equal(ok, grp[:, None] == grp[None, :])


def test_latency_budget_and_jitter_distribution() -> None:
    plan = plan_from_table({"latency": "50ms", "jitter": "20ms", "seed": 1})
    within_60 = np.stack([delivery_mask(plan, np.arange(40), t, 8, budget_ms=60.0)
                          for t in range(20)])
    frac = within_60[..., ~np.eye(8, dtype=bool)].mean()
    assert frac == pytest.approx(0.5, abs=0.03)  # P(50 + 20 U <= 60) = 0.5
    off_diagonal = ~np.eye(8, dtype=bool)
    assert not delivery_mask(plan, np.arange(4), 0, 8, budget_ms=49.0)[:, off_diagonal].any()


def test_token_bucket_queues_and_drops_at_the_configured_rate() -> None:
    q = TokenBucket(rate=1000.0, depth=200.0)
    waits = [q.send(100, now=0.01 * k) for k in range(100)]  # 10 kB/s offered, queued
    assert waits[0] == 0.0 and waits[-1] == pytest.approx((100 * 100 - 200 - 1000 * 0.99) / 1000,
                                                           rel=0.05)
    d = TokenBucket(rate=1000.0, depth=200.0)
    sent = [d.send(100, now=0.01 * k, overflow="drop") is not None for k in range(1000)]
    assert np.mean(sent) == pytest.approx(0.1, abs=0.01)  # 1 kB/s of 10 kB/s gets through
    e = TokenBucket(rate=1000.0, depth=200.0)  # expire: queued only while it leaves in time
    waits = [e.send(100, now=0.01 * k, overflow="expire", deadline=0.01 * k + 0.05)
             for k in range(1000)]
    kept = [w for w in waits if w is not None]
    assert max(kept) <= 0.05 + 1e-9 and np.mean([w is not None for w in waits]) == pytest.approx(
        0.1, abs=0.01)  # the rate still holds, and nothing waits past its deadline
    assert e.send(10_000, now=20.0, overflow="expire", deadline=20.5) is None  # costs nothing:
    assert e.send(200, now=20.0, overflow="expire", deadline=20.0) == 0.0  # the bucket is full


def test_expire_keeps_trajectories_on_time_under_a_cap_that_queues_them_late() -> None:
    """At 60 B/s (a 2-s tick carries 120 bytes) a 108-byte trajectory and a 128-byte hidden
    state do not both fit: queued, the hidden state delays the next trajectories past their
    deadline and every copy comes late; expired, the hidden state is never sent (counted as
    dropped_bw) and every trajectory arrives on time."""
    from swarm.net.channel import DROPPED, LATE, OK, VirtualChannel

    for overflow, traj_fate, hidden_fate in (("queue", LATE, LATE), ("expire", OK, DROPPED)):
        ch = VirtualChannel(plan_from_table({"bandwidth": "60B/s", "overflow": overflow}, 0, 3),
                            3, 2.0)
        senders = np.ones((1, 3), dtype=bool)
        for t in range(10):
            tr = ch.traj(np.array([0]), t, senders, np.full((1, 3), 108.0))
            hi = ch.hidden(np.array([0]), t, senders, np.full((1, 3), 128.0))
        off = ~np.eye(3, dtype=bool)
        assert (tr.fate[0][off] == traj_fate).all() and (hi.fate[0][off] == hidden_fate).all()


def test_radio_bundles_arrive_after_latency_and_late_copies_are_cut() -> None:
    cfg = WorldConfig(n_robots=3, comm_range=float("inf"))
    radio = Radio(cfg, plan_from_table({"latency": "100ms"}))
    pos = np.array([[0, 0], [0, 1], [0, 2]])
    senders = {i: (bytes([i]) * 10, 1.0) for i in range(3)}
    out = radio.bundles(0, 0, pos, senders, deadline=1.5)
    for when, payloads in out.values():
        assert when == pytest.approx(1.1) and len(payloads) == 3
    radio2 = Radio(cfg, plan_from_table({"latency": "100ms"}))
    out2 = radio2.bundles(0, 0, pos, senders, deadline=1.05)
    assert all(len(p) == 1 for _, p in out2.values())  # only the own message is on time
    assert radio2.counters.late == 6


def test_a_hidden_state_that_waited_for_tokens_counts_as_queued_on_the_real_clock() -> None:
    """A 266-byte hidden state under a 150 B/s cap (150 bytes deep) waits 0.77 s: late for a
    0.05-s deadline, and counted queued by kind, like a trajectory message that waited."""
    radio = Radio(WorldConfig(n_robots=3), plan_from_table({"bandwidth": "150B/s"}))
    radio.pred = np.array([-1, 0, 1])
    assert radio.hidden_deliveries(0, 0, 0, 266, now=1.0, deadline=1.05) == []
    hidden = radio.counters.totals()["by_kind"]["hidden"]
    assert hidden["queued"] == hidden["late"] == 1 and radio.counters.queued == 1
    assert radio.counters.faulted_links() == {"0-1": [0, 0, 1, 1]}


def test_queued_trajectory_copies_count_alike_on_both_clocks() -> None:
    """A trajectory copy whose sender's message waited for tokens is queued whatever became of
    it (here cut by a partition), on the real clock as on the virtual one (`count_traj`)."""
    cfg = WorldConfig(n_robots=3, comm_range=float("inf"))
    plan = plan_from_table({"bandwidth": "150B/s", "partition": "0/1-2"})
    pos = np.array([[0, 0], [0, 1], [0, 2]])
    real, virtual = Radio(cfg, plan), Radio(cfg, plan)
    real.bundles(0, 0, pos, {i: (bytes(266), 1.0) for i in range(3)}, deadline=1.5)
    virtual.use_virtual_clock(2.0)
    virtual.virtual_bundles(0, 0, pos, {i: bytes(266) for i in range(3)})
    for radio in (real, virtual):
        assert radio.counters.kinds["traj"]["queued"] == 6 and radio.counters.cut == 4


# ------------------------------------------------------------------------------- real swarm


def _run(tmp_path: Path, name: str, *extra: str, timeout: float = 180) -> dict:
    out = tmp_path / f"{name}.json"
    policy = () if "--policy" in extra else ("--policy", "nearest-frontier")
    r = swarm("run", "--headless", "--run-id", name, "--json", str(out), *policy, *extra,
              timeout=timeout)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(out.read_text())


def test_zero_faults_are_identical_to_no_fault_layer(tmp_path: Path) -> None:
    res = _run(tmp_path, "zero", "--robots", "3", "--episodes", "2", "--seed", "5",
               "--loss", "0", "--latency", "0ms", "--jitter", "0ms")
    cfg = WorldConfig(n_robots=3)
    ev = evaluate(cfg, make_policy("nearest-frontier", cfg), 5, 2, record_actions=True)
    assert np.array_equal(np.array(res["actions"]), np.stack(ev.actions, 1))
    m = res["messages"]
    assert m["lost"] == m["late"] == m["cut"] == m["queued"] == 0


def test_swarm_loss_statistics_and_partition_counts(tmp_path: Path) -> None:
    res = _run(tmp_path, "loss", "--robots", "4", "--episodes", "3", "--comm-range", "inf",
               "--policy", "random", "--loss", "0.3", "--fault-seed", "3")
    m = res["messages"]
    copies = 3 * 30 * 4 * 3  # ticks x senders x other receivers
    assert m["lost"] == pytest.approx(0.3 * copies, rel=0.15)
    assert m["traj_delivered"] == 3 * 30 * 4 + copies - m["lost"]
    res = _run(tmp_path, "part", "--robots", "4", "--episodes", "1", "--comm-range", "inf",
               "--policy", "random", "--partition", "0-1/2-3")
    m = res["messages"]
    assert m["cut"] == 30 * 8  # 8 cross-group copies every tick, no more
    assert m["traj_delivered"] == 30 * 8  # 2 groups x 2 x 2, own messages included
    assert m["lost"] == 0


def test_on_the_real_clock_late_copies_sum_over_kinds_and_stale_messages_are_apart(
        tmp_path: Path) -> None:
    """`late` counts copies (the sum of `by_kind[*].late`); messages that reached the world
    after their tick are whole messages, counted as `stale` on both clocks. (10 ticks are plenty:
    ~40 copies get through the loss, a dozen or more of them late.)"""
    res = _run(tmp_path, "rlate", "--robots", "3", "--episodes", "1", "--horizon", "10",
               "--seed", "2", "--clock", "real", "--tick-timeout", "0.5", "--latency", "350ms",
               "--jitter", "100ms", "--loss", "0.3")
    m = res["messages"]
    assert m["late"] > 0 and m["late"] == sum(k["late"] for k in m["by_kind"].values())
    assert isinstance(m["stale"], int) and m["stale"] >= 0


def test_crash_and_restart_mid_episode(tmp_path: Path) -> None:
    res = _run(tmp_path, "crashrs", "--robots", "3", "--episodes", "6", "--crash", "1@10",
               "--restart", "1@40", "--pace", "40")
    assert res["completed"] == 6
    assert [f.split("@")[0] for f in res["process_faults"]] == ["crash 1", "restart 1"]
    assert res["robot_restarts"] == 1 and res["robots_lost"] == 0
    acts = np.array(res["actions"])  # [ep, T, N]
    assert (acts[-1, :, 1] != 0).any()  # robot 1 acts again in the last episode
    logs = Path(res["logs"])  # a run with a crash keeps its children's logs, and names them
    assert (logs / "world.log").exists() and (logs / "robot1.log").exists()


def test_heavy_loss_and_latency_never_deadlock(tmp_path: Path) -> None:
    """50% loss + 300 ms latency for 100 ticks: every tick completes within its deadline."""
    t0 = time.monotonic()
    res = _run(tmp_path, "heavy", "--robots", "3", "--episodes", "4", "--horizon", "25",
               "--loss", "0.5", "--latency", "300ms", "--tick-timeout", "0.5", timeout=240)
    assert res["ticks"] == 100 and res["completed"] == 4
    assert time.monotonic() - t0 < 100 * 0.5 + 30
    assert res["messages"]["lost"] > 0


@pytest.mark.procs
def test_live_fault_change_takes_effect_within_one_tick(tmp_path: Path) -> None:
    run_id = "livef"
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "3", "--policy",
         "random", "--episodes", "4", "--pace", "2", "--comm-range", "inf", "--run-id", run_id],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        statuses = [json.loads(proc.stdout.readline())["status"]]
        r = swarm("fault", "--run", run_id, "--partition", "0/1/2", timeout=30)
        assert r.returncode == 0, r.stderr
        sent_at = json.loads(r.stdout)["sent_at"]
        for _ in range(60):
            rec = json.loads(proc.stdout.readline())["status"]
            statuses.append(rec)
            if rec["faults"]:
                break
        assert rec["faults"] == ["partition 0/1/2"]
        # ticks that ended after the command was sent but still ran without it: at most the one
        # in progress when it arrived
        assert sum(1 for s in statuses if s["wall"] > sent_at and not s["faults"]) <= 1
        # the world reads controls between ticks too (it waits ~0.5 s between ticks of a few
        # ms): the first tick to end after the command runs with it, unless it was in play then
        first = next(s for s in statuses if s["wall"] > sent_at)
        assert first["faults"] or first["wall"] < sent_at + 0.1, (first["wall"] - sent_at)
        # and it bites: from the next tick on, no robot hears another
        nxt = json.loads(proc.stdout.readline())["status"]
        assert nxt["radio"]["cut"] - rec["radio"]["cut"] == 6
    finally:
        proc.send_signal(signal.SIGINT)  # a clean stop: the supervisor ends its children
        proc.communicate(timeout=10)


@pytest.mark.procs
def test_a_live_fault_must_fit_the_run_and_a_crash_waits_for_its_tick(tmp_path: Path) -> None:
    """`swarm fault` asks the run first: a partition or robot beyond its robots, or no run at
    the endpoint, is one line and exit 2 with nothing sent; `--crash ROBOT@TICK` waits for run
    tick TICK (it used to strike at once)."""
    run_id, out = "livec", tmp_path / "r.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "3", "--policy",
         "random", "--episodes", "5", "--horizon", "20", "--pace", "10", "--run-id", run_id,
         "--json", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        at = json.loads(proc.stdout.readline())["status"]["run_tick"] + 40  # 4 s ahead
        r = swarm("fault", "--run", run_id, "--crash", f"2@{at}", timeout=30)
        assert r.returncode == 0, r.stderr
        r = swarm("fault", "--run", run_id, "--crash", "0", timeout=30)  # ROBOT alone: at once
        assert r.returncode == 0, r.stderr  # (refused for a day: "use ROBOT@TICK"; sent before
        # the refusals below: on a loaded machine they took until the run's end)
        bad = [subprocess.Popen([sys.executable, "-m", "swarm.cli", "fault", "--run", run_id,
                                 *args], cwd=ROOT, stderr=subprocess.PIPE, text=True)
               for args in (("--partition", "0-1/2-9"), ("--crash", "7"), (
                   "--loss", "0.1", "--connect", "tcp/127.0.0.1:1", "--wait", "0.5"),
                   ("--crash", "1@999999"),  # (a tick the run never reaches: refused too)
                   ("--hang", "1@0"))]  # (one it has played: it struck at a later tick)
        errs = [p.communicate(timeout=30)[1] for p in bad]  # (side by side: the run is
        for p, err in zip(bad, errs, strict=False):        # still there for the others)
            assert p.returncode == 2 and len(err.strip().splitlines()) == 1, err
        assert all("robots 0..2" in e for e in errs[:2]) and "did not answer" in errs[2], errs
        assert "beyond the run's last tick 99" in errs[3], errs[3]
        assert "ROBOT@TICK 0: run livec is at tick" in errs[4], errs[4]
        err = proc.communicate(timeout=120)[1]
        assert "left the run" not in err, err  # (UA pass: a live crash was said unplanned)
    finally:
        if proc.poll() is None:
            proc.kill()
    res = json.loads(out.read_text())
    assert len(res["process_faults"]) == 2, res["process_faults"]
    fired = dict(f.split("@") for f in res["process_faults"])
    assert at <= int(fired["crash 2"]) <= at + 2  # (logged at the status that fired it)
    assert "crash 0" in fired  # (at once: at the tick it reached the run, whichever that was)
    assert res["process_faults_pending"] == []  # (one for a tick never reached is refused)


@pytest.mark.procs
def test_a_process_fault_to_a_world_by_hand_is_refused_and_a_link_fault_goes(
        tmp_path: Path) -> None:
    """A world started by hand has no supervisor to kill or stop a robot: `swarm fault --crash`
    / `--hang` to it is one line and exit 2 with nothing sent (it printed the control and exited
    0, and nothing happened); a link fault still goes, and applies."""
    import contextlib
    import threading

    import zenoh

    from swarm.common import spawn
    from swarm.net.keys import Keys
    from swarm.net.messages import K_CONTROL, K_STATUS, pack_record, unpack_record
    from swarm.net.zconfig import ZenohOptions, free_port

    run_id, hub, out = "handpf", f"tcp/127.0.0.1:{free_port()}", tmp_path / "w.json"
    logs = [tmp_path / f"p{k}.log" for k in range(3)]  # (a failure shows why a process ended)
    commands = (["world", "--robots", "2", "--policy", "random", "--episodes", "1000", "--pace",
                 "20", "--listen", hub, "--json", str(out)],
                ["robot", "--id", "0", "--connect", hub], ["robot", "--id", "1", "--connect", hub])
    procs = [subprocess.Popen([sys.executable, "-m", "swarm.cli", *args, "--run-id", run_id],
                              cwd=ROOT, stdout=subprocess.DEVNULL,
                              stderr=log.open("w"))  # noqa: SIM115
             for log, args in zip(logs, commands, strict=True)]
    try:  # both robots in the run first (robots by hand join seconds after the world plays)
        spawn.wait_port("127.0.0.1", int(hub.rsplit(":", 1)[1]), procs[0], 60.0)
        both = threading.Event()

        def seen(sample: zenoh.Sample) -> None:
            with contextlib.suppress(Exception):  # (any record but a status with both alive)
                if unpack_record(sample.payload.to_bytes(), K_STATUS)["alive"] == [True, True]:
                    both.set()

        with zenoh.open(ZenohOptions(connect=[hub]).to_config()) as s:
            s.declare_subscriber(Keys(run_id).status, seen)
            assert both.wait(60), [log.read_text()[-500:] for log in logs]
        bad = [subprocess.Popen([sys.executable, "-m", "swarm.cli", "fault", "--run", run_id,
                                 "--connect", hub, "--wait", "60", *args], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
               for args in (("--crash", "1@20000"), ("--hang", "0"), ("--restart", "1"))]
        for p in bad:
            sent, err = p.communicate(timeout=90)
            assert p.returncode == 2 and len(err.strip().splitlines()) == 1, err
            assert f"run {run_id} has no supervisor" in err and "nothing was sent" in err, err
            assert sent == ""
        r = swarm("fault", "--run", run_id, "--connect", hub, "--loss", "0.5", timeout=60)
        assert r.returncode == 0, r.stderr  # (it returns once a status came after the change)
        with zenoh.open(ZenohOptions(connect=[hub]).to_config()) as s:
            s.put(Keys(run_id).control, pack_record(K_CONTROL, {"stop": True}))
            assert procs[0].wait(timeout=30) == 3, logs[0].read_text()[-1500:]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    res = json.loads(out.read_text())
    changes = res["fault_changes"]["changes"]  # the link fault alone reached the world
    assert len(changes) == 1 and any("loss" in f for f in changes[0]["faults"]), changes
    assert res["robots_lost"] == 0 and res["never_joined"] == []  # (nobody crashed or hung)


@pytest.mark.procs
def test_experiment_sweep_writes_csv_png_and_resumes(tmp_path: Path) -> None:
    r = swarm("experiment", "deploy/experiments/tiny.toml", "--out", str(tmp_path), "--seeds",
              "0", timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = (tmp_path / "tiny.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 * 2  # header + policies x values (one seed)
    assert (tmp_path / "tiny.png").read_bytes()[:4] == b"\x89PNG"
    md = (tmp_path / "tiny.md").read_text()
    assert "swarm experiment deploy/experiments/tiny.toml" in md and "nearest-frontier" in md
    lost = {(row.split(",")[0], row.split(",")[1]): int(row.split(",")[10]) for row in rows[1:]}
    assert all(v == 0 for (p, val), v in lost.items() if val == "0.0")
    assert all(v > 0 for (p, val), v in lost.items() if val == "0.5")
    before = (tmp_path / "tiny.csv").read_text()
    r = swarm("experiment", "deploy/experiments/tiny.toml", "--out", str(tmp_path), "--seeds",
              "0", "--resume")
    assert r.returncode == 0 and (tmp_path / "tiny.csv").read_text() == before


def test_batched_eval_applies_the_radios_exact_loss_draws(tmp_path: Path) -> None:
    """Loss and partition do not depend on wall time: swarm and batch drop the same messages."""
    res = _run(tmp_path, "lossq", "--robots", "4", "--episodes", "2", "--seed", "9",
               "--loss", "0.4", "--partition", "0-2/3", "--fault-seed", "5")
    cfg = WorldConfig(n_robots=4)
    plan = plan_from_table({"loss": 0.4, "partition": "0-2/3", "seed": 5})
    ev = evaluate(cfg, make_policy("nearest-frontier", cfg), 9, 2, record_actions=True,
                  faults=plan)
    clean = evaluate(cfg, make_policy("nearest-frontier", cfg), 9, 2, record_actions=True)
    assert np.array_equal(np.array(res["actions"]), np.stack(ev.actions, 1))
    assert not np.array_equal(np.stack(ev.actions, 1), np.stack(clean.actions, 1))


def test_chained_memory_policy_under_loss_acts_as_the_batched_eval(tmp_path: Path) -> None:
    """CommAttn with the team memory under 40% loss: each robot process folds what it heard
    into its own memory and, when its predecessor's hidden-state message is lost, gives up at its
    per-hop slot and decodes without it, exactly the batched evaluator's `chain_ok` rule. No
    downstream robot misses the tick, so every action equals the batched one."""
    import torch

    from policies.checkpoint import save_checkpoint

    cfg = WorldConfig(height=8, width=8, n_static=6, n_dynamic=4, n_robots=4, horizon=8,
                      add_every=2, vision=5, comm_range=6.0)
    toml = tmp_path / "w.toml"
    toml.write_text("[world]\n" + "".join(f"{k} = {getattr(cfg, k)}\n" for k in (
        "height", "width", "n_static", "n_dynamic", "n_robots", "horizon", "add_every",
        "vision", "comm_range")))
    torch.manual_seed(2)
    pol = make_policy("commattn", cfg)
    pol.set_model(team_memory=True)
    ckpt = tmp_path / "mem.pt"
    save_checkpoint(ckpt, pol.payload())
    res = _run(tmp_path, "memloss", "--config", str(toml), "--policy", "commattn",
               "--checkpoint", str(ckpt), "--episodes", "2", "--seed", "3", "--loss", "0.4",
               "--fault-seed", "8", "--tick-timeout", "2.0")
    plan = plan_from_table({"loss": 0.4, "seed": 8})
    ev = evaluate(cfg, make_policy("commattn", cfg, checkpoint=ckpt), 3, 2, record_actions=True,
                  faults=plan)
    assert res["messages"]["lost"] > 0 and res["timeouts"] == 0
    assert np.array_equal(np.array(res["actions"]), np.stack(ev.actions, 1))


def test_a_run_whose_robots_all_left_while_its_world_plays_on_is_ended(tmp_path: Path) -> None:
    """A world stopped (SIGSTOP) past its Zenoh lease lost every robot (each saw its token gone
    and left, exit 0); resumed, it played the other ~70% of the episodes with nobody and the run
    exited 0 with those averaged in (elratio 0.53 for 0.99; UA pass 79). `Fleet.deserted` is
    the line `swarm run` now fails with, once no robot is left for `grace` s; robots crashed on
    purpose (a planned fault) and a world that is not playing (its end) are not a desertion."""
    from collections.abc import Callable

    from swarm.common.spawn import EXIT_INCOMPLETE
    from swarm.net.faults import ProcessFault
    from swarm.procs.fleet import Fleet

    def exits(code: int) -> Callable[[int], subprocess.Popen[bytes]]:
        return lambda i: subprocess.Popen([sys.executable, "-c", f"raise SystemExit({code})"])

    done = Fleet(exits(0), tmp_path, restart_crashed=False)  # (0: after the world's `end`)
    done.start(0)
    done.procs[0].wait()
    done.check()  # (a supervisor behind on its inbox reaps them before it reads the result)
    assert not done.procs and not done.left and done.deserted(True, grace=0.0) is None
    fleet = Fleet(exits(EXIT_INCOMPLETE), tmp_path, restart_crashed=False)  # (WorldLeft)
    for i in range(2):
        fleet.start(i)
    for p in fleet.procs.values():
        p.wait()
    fleet.check()
    assert fleet.left == {0, 1} and not fleet.procs and not fleet.errors
    assert fleet.deserted(False, grace=0.0) is None  # (the world's own end)
    assert fleet.deserted(True, grace=60.0) is None  # (its end may still be on its way)
    assert fleet.deserted(True, grace=0.0) == (
        "every robot left the run before its end (robots [0, 1]: the world's token was gone for "
        "them; was the world stopped past its Zenoh lease?): no robot played the rest of its "
        "episodes")

    crashed = Fleet(lambda i: subprocess.Popen([sys.executable, "-c", "import time; "
                                                "time.sleep(60)"]), tmp_path, False)
    crashed.start(0)
    crashed.fault(ProcessFault("crash", 0, 5), 5)
    crashed.procs[0].wait()
    crashed.check()
    assert not crashed.procs and crashed.deserted(True, grace=0.0) is None  # (planned)


def test_the_fleet_counts_each_death_once_and_says_the_unplanned(tmp_path: Path) -> None:
    """`Fleet` on real child processes: a planned crash is counted where it is done (also when
    a restart of the same tick replaces the process before anyone looks), an unplanned death
    is counted once by the check and kept with how it ended, a hang and its restart are not
    deaths; nothing is counted twice."""
    from swarm.net.faults import ProcessFault
    from swarm.procs.fleet import Fleet

    def spawn(i: int) -> subprocess.Popen[bytes]:
        return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])

    (tmp_path / "robot3.log").write_text("ValueError: an earlier run's robot 3\n")
    fleet = Fleet(spawn, tmp_path, restart_crashed=False)
    try:
        for i in range(4):
            fleet.start(i)
        first = fleet.procs[0]
        assert fleet.fault(ProcessFault("crash", 0, 5), 5) == "crash 0@5"
        assert fleet.fault(ProcessFault("restart", 0, 5), 5) == "restart 0@5"
        assert fleet.procs[0] is not first and fleet.up(0)
        fleet.fault(ProcessFault("crash", 1, 7), 7)
        fleet.fault(ProcessFault("hang", 2, 8), 8)
        assert fleet.fault(ProcessFault("hang", 2, 9), 9) == "hang 2@9 (hung already: nothing done)"
        fleet.fault(ProcessFault("restart", 2, 10), 10)
        fleet.procs[3].send_signal(signal.SIGKILL)  # nobody planned this one
        fleet.procs[3].wait()
        fleet.check()
        fleet.check()
        assert (fleet.crashes, fleet.restarts) == (3, 2)
        assert fleet.errors == {"robot 3": "killed by SIGKILL"}
        assert sorted(fleet.procs) == [0, 2] and not fleet.hung and not fleet.killed
        # a death nobody planned, then a restart before any check: counted and said (review)
        fleet.procs[2].send_signal(signal.SIGKILL)
        fleet.procs[2].wait()
        fleet.fault(ProcessFault("hang", 0, 11), 11)  # (hung: a later death must forget it)
        fleet.fault(ProcessFault("restart", 2, 12), 12)
        assert (fleet.crashes, fleet.restarts) == (4, 3) and fleet.up(2)
        assert fleet.errors["robot 2"] == "killed by SIGKILL"
        fleet.procs[0].send_signal(signal.SIGCONT)
        fleet.procs[0].terminate()  # (SIGTERM: an exit that is not 0)
        fleet.procs[0].wait()
        fleet.check()
        assert 0 not in fleet.hung and fleet.crashes == 5 and 0 not in fleet.procs
        fleet.procs[2] = subprocess.Popen([sys.executable, "-c", "pass"])  # left on its own
        fleet.procs[2].wait()
        fleet.check()
        assert fleet.crashes == 5 and "robot 2" in fleet.errors and not fleet.procs
    finally:
        for p in fleet.procs.values():
            p.kill()
            p.wait()
