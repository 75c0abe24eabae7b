"""In-range strays on a run's keys (UA pass 51): one message that passes the range checks must
not end a run, fire its planned faults early, or silence a robot for good."""

from __future__ import annotations

import dataclasses
import json
import tomllib
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zenoh
from test_hardening import TINY, hub_of, start_run, three_statuses

from swarm.net.keys import Keys
from swarm.net.messages import (
    K_ACTION,
    K_RESULT,
    K_STATUS,
    SCHEMA,
    Action,
    BadMessage,
    Obs,
    pack_record,
    unpack_record,
)
from swarm.net.records import check_world_result
from swarm.net.zconfig import ZenohOptions
from swarm.procs.robot_status import TickGuard
from swarm.procs.status_order import StatusOrder
from world.config import WorldConfig


def test_a_header_of_float_or_bool_is_not_the_schema() -> None:
    cfg = WorldConfig()
    good = Action(0, 4, 0, 0, 0.0).pack()
    assert Action.unpack(good, cfg).t == 4
    for head in ([1.0, K_ACTION], [True, K_ACTION], [SCHEMA, float(K_ACTION)]):
        body = msgpack.unpackb(good)[2:]
        with pytest.raises(BadMessage):
            Action.unpack(msgpack.packb([*head, *body]), cfg)


def test_a_half_made_or_foreign_result_is_refused() -> None:
    """A forged `{"policy", "completed": 0}` ended a run, its real result lost; a whole one with
    a figure that is no number would crash the table that prints it."""
    real = {"policy": "commattn", "run_id": "r", "completed": 1, "elratio_mean": 0.5,
            "success_rate": 0.0, "actions": [[[0, 0]] * 3], "ticks": 3, "messages": {}}
    assert check_world_result(dict(real), "commattn", 2, "r", 3) == real
    none = {**real, "completed": 0, "actions": [], "elratio_mean": None,
            "reward_mean": float("nan")}
    assert check_world_result(dict(none), "commattn", 2, "r", 3) == none  # (a stop before one)
    for bad in ({"run_id": "other"}, {"actions": []}, {"actions": [[[0, 0]] * 2]},
                {"ticks": 7}, {"messages": None}, {"completed": 3},
                {"reward_mean": "x"}, {"robots_lost": "x"}, {"elratio_std": float("nan")}):
        with pytest.raises(BadMessage):
            check_world_result({**real, **bad}, "commattn", 2, "r", 3)
    with pytest.raises(BadMessage):
        check_world_result({"policy": "commattn", "completed": 0}, "commattn", 2, "r", 3)


def status(tick: int) -> dict:
    return {"run_tick": tick}


def test_a_status_that_skips_ahead_waits_for_the_next_to_follow_it() -> None:
    order = StatusOrder()
    assert order.offer(status(1)) == (True, None) and order.offer(status(2)) == (True, None)
    assert order.offer(status(90)) == (False, None)  # held: a forgery, or a skip
    ok, dropped = order.offer(status(3))  # the world went on from 2: 90 was not its
    assert ok and "skipped ahead" in (dropped or "") and order.tick == 3
    assert order.offer(status(6)) == (False, None)  # a real skip (an inbox that overflowed)
    assert order.offer(status(7)) == (True, None) and order.tick == 7
    with pytest.raises(BadMessage):
        order.offer(status(5))  # a replay
    assert order.offer(status(20)) == (False, None)  # held at the end: the last tick's ...
    assert order.end(20) == (status(20), None) and order.tick == 20
    assert order.offer(status(40)) == (False, None)  # ... or not
    held, dropped = order.end(21)
    assert held is None and "none followed" in (dropped or "")


def test_an_observation_far_ahead_does_not_silence_the_robot() -> None:
    g = TickGuard(horizon=30, first_episode=0, episodes=6)
    for t in range(11):
        g.obs(0, t, 5, 5)
    g.obs(5, 29, 5, 5)  # forged, in range: acted on (without --secure nothing tells it apart)
    g.obs(0, 11, 5, 6)  # the world's next after tick 10: the skip was not the world's
    assert g.last == (0, 11, 5, 6) and g.before_skip is None
    for old in ((0, 5), (0, 11), (0, 10)):  # replays stay refused
        with pytest.raises(BadMessage):
            g.obs(*old, 5, 6)
    g.obs(0, 20, 5, 6)  # a real skip (the robot was stopped) ...
    with pytest.raises(BadMessage):
        g.obs(0, 13, 5, 6)  # ... and an old one after it: not the next of tick 11
    with pytest.raises(BadMessage):
        g.obs(0, 12, 9, 9)  # the next of tick 11 but out of its reach
    g.obs(0, 21, 5, 6)
    assert g.before_skip is None  # (a step of one: no way back)
    with pytest.raises(BadMessage):
        g.obs(0, 12, 5, 6)
    g.obs(0, 30, 5, 6)
    g.obs(1, 0, 5, 6)  # an episode's done observation, then the next episode's first


@pytest.mark.procs
def test_in_range_strays_leave_a_run_as_it_would_have_been(tmp_path: Path) -> None:
    """Mid-run, a half-made result, a status of the run's last tick and an observation of an
    episode far ahead: the run completes (it ended at once), the status stream goes on (it
    froze), no robot waits out the watchdog (robot 2 did at every tick after), each stray is
    counted once. Robot 2 acts on the observation (in range: without `--secure` nothing tells
    it from the world's), so its actions may differ from a clean run's from there."""
    run_id = "stray1"
    proc = start_run(tmp_path, run_id, "--policy", "nearest-frontier", "--episodes", "3",
                     "--seed", "5", "--pace", "12", "--watchdog", "30")
    cfg = WorldConfig(**tomllib.loads(TINY)["world"])
    try:
        hub = hub_of(run_id, proc)
        keys = Keys(run_id)
        got: dict[str, bytes] = {}
        with zenoh.open(ZenohOptions(mode="client", connect=[hub]).to_config()) as session:
            subs = [session.declare_subscriber(k, lambda s, n=n: got.setdefault(
                n, s.payload.to_bytes())) for n, k in (("status", keys.status),
                                                       ("obs", keys.obs(2)))]
            three_statuses(session, keys)
            rec = unpack_record(got["status"], K_STATUS)
            last = 3 * cfg.horizon
            session.put(keys.status, pack_record(K_STATUS, {**rec, "ep": 2, "t": cfg.horizon,
                                                            "run_tick": last}))
            obs = Obs.unpack(got["obs"], cfg)
            session.put(keys.obs(2), dataclasses.replace(obs, ep=2, t=cfg.horizon - 1).pack())
            session.put(keys.result, pack_record(K_RESULT, {"policy": "nearest-frontier",
                                                             "run_id": run_id, "completed": 0}))
            for s in subs:
                s.undeclare()
        assert proc.wait(timeout=120) == 0, proc.stderr.read().decode()[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["completed"] == 3 and res["timeouts"] == 0, res["timeouts"]
    assert res["supervisor_bad"] == 2, res  # the status held, then dropped; the result
    assert res["robot_status"]["2"]["bad"] == 0  # acted on (in range), then left behind
    assert np.array(res["actions"]).shape == (3, cfg.horizon, cfg.n_robots)
    assert res["ticks"] == 3 * cfg.horizon


@pytest.mark.procs
def test_robots_that_left_on_a_stray_end_record_are_said(tmp_path: Path) -> None:
    """A run-end record mid-run (in range: it names the run) makes every robot leave, saying it
    is done; the world plays on without them. The run said nothing and exited 0."""
    run_id = "stray2"
    proc = start_run(tmp_path, run_id, "--policy", "nearest-frontier", "--episodes", "2",
                     "--pace", "12")
    try:
        hub = hub_of(run_id, proc)
        keys = Keys(run_id)
        with zenoh.open(ZenohOptions(mode="client", connect=[hub]).to_config()) as session:
            three_statuses(session, keys)
            session.put(keys.end, pack_record(K_RESULT, {"run_id": run_id}))
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["robots_lost"] == 3 and res["completed"] == 2, res
    assert "3 robot(s) left the run before its end, each saying the run had ended" in \
        err.decode(), err.decode()[-2000:]
