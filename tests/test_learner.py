"""The learner process, field training and rollout workers: real processes, real Zenoh on
loopback (scouting off), real torch models."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import zenoh
from conftest import ROOT, swarm

from policies import make_policy
from policies.checkpoint import load_checkpoint, save_checkpoint
from swarm.learn.config import TrainConfig
from swarm.learn.evaluate import evaluate
from swarm.learn.join import episodes_of, rollout_of
from swarm.learn.rollout import collect
from swarm.learn.update import advantages, backward, normaliser, update
from swarm.learn.weights import adopt, weights_of
from swarm.net.keys import Keys
from swarm.net.learning import EpisodeRollout, LearnerGate, RobotRollout, Weights
from swarm.net.messages import BadMessage
from swarm.net.zconfig import ZenohOptions, free_port
from world.config import WorldConfig

SMALL = WorldConfig(height=8, width=8, n_static=6, n_dynamic=4, n_robots=3, horizon=8,
                    add_every=2, vision=3, comm_range=4.0, recent_len=4)


def spawn(*args: str, log: Path | None = None) -> subprocess.Popen[bytes]:
    err = open(log, "ab") if log else subprocess.DEVNULL  # noqa: SIM115
    return subprocess.Popen([sys.executable, "-m", "swarm.cli", *args], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=err, stdin=subprocess.DEVNULL)


def initial(tmp: Path, cfg: WorldConfig, seed: int = 0, name: str = "commattn") -> Path:
    torch.manual_seed(seed)
    path = tmp / "init.pt"
    save_checkpoint(path, make_policy(name, cfg).payload({"seed": seed}))
    return path


def world_toml(tmp: Path, cfg: WorldConfig, train: str = "") -> Path:
    path = tmp / "exp.toml"
    fields = {k: getattr(cfg, k) for k in ("height", "width", "n_static", "n_dynamic",
                                           "n_robots", "horizon", "add_every", "vision",
                                           "comm_range", "recent_len")}
    path.write_text("[world]\n" + "".join(f"{k} = {v}\n" for k, v in fields.items())
                    + (f"[train]\n{train}\n" if train else ""))
    return path


@pytest.mark.parametrize("memory", [False, True])
def test_wire_records_round_trip_into_the_trainers_rollout(memory: bool) -> None:
    """Trainer rollout -> EpisodeRollout payloads -> Rollout: same views, actions and rewards,
    and the same REINFORCE step (with the team memory: the learner refolds each robot's memory
    from the records); bad payloads are one-line BadMessages."""
    pol = make_policy("commattn", SMALL)
    pol.set_model(team_memory=memory)  # on by default
    roll = collect(pol, SMALL, 4, np.arange(3))
    wire = [EpisodeRollout.unpack(e.pack(), SMALL) for e in episodes_of(roll, version=2)]
    assert [e.ep for e in wire] == [0, 1, 2] and all(e.version == 2 for e in wire)
    back = rollout_of(wire, pol)
    for a, b in zip(roll.views, back.views, strict=True):
        assert np.array_equal(a.msgs.visited, b.msgs.visited) and np.array_equal(a.hears, b.hears)
        assert np.array_equal(a.receivers, b.receivers) and np.array_equal(a.msgs.pos, b.msgs.pos)
    assert np.array_equal(np.stack(roll.actions), np.stack(back.actions))
    np.testing.assert_allclose(back.logp, roll.logp)
    assert back.stale is not None and not back.stale.any()
    np.testing.assert_allclose(back.reward, roll.reward)
    np.testing.assert_allclose(back.value, roll.value, atol=1e-5)
    cfg = TrainConfig(batch=3)
    p1, p2 = (make_policy("commattn", SMALL) for _ in range(2))
    p2.net.load_state_dict(p1.net.state_dict())
    for p in (p1, p2):
        p.set_model(team_memory=memory)
    update(p1, torch.optim.Adam(p1.net.parameters(), lr=cfg.lr), roll, cfg)
    update(p2, torch.optim.Adam(p2.net.parameters(), lr=cfg.lr), back, cfg)
    for k, v in p1.net.state_dict().items():  # (Adam divides by sqrt(v): a gradient near zero
        # that differs in its last float bits, with another summation order under another
        # thread count, moves a weight by up to ~lr; 1 of 15,360 did by 1.5e-5 in a full run)
        torch.testing.assert_close(p2.net.state_dict()[k], v, rtol=1e-4, atol=3e-5)
    good = wire[0].pack()
    for bad in (b"\x00junk", good[:-9], RobotRollout(0, 7, []).pack()):
        with pytest.raises(BadMessage) as err:
            EpisodeRollout.unpack(bad, SMALL)
        assert "\n" not in str(err.value)


def test_stale_episodes_are_weighted_by_truncated_importance_ratios() -> None:
    """An episode acted by older weights: each decision's policy-gradient term is weighted by
    min(is_clip, pi_now / pi_acted). Same weights: ratio 1, the plain gradient; acting
    probability twice today's: ratio 1/2, half the gradient; half today's: ratio 2, truncated
    to 1; fresh episodes are never weighted."""
    torch.manual_seed(3)
    pol = make_policy("commnet", SMALL)
    wire = episodes_of(collect(pol, SMALL, 4, np.arange(3)), version=2)
    cfg = TrainConfig(batch=3, alpha=0.0, ent_coef=0.0)

    def grads(shift: float | None, version: int) -> list[torch.Tensor]:
        roll = rollout_of(wire, pol, version=version)
        if shift is not None:
            roll.logp = roll.logp + shift  # type: ignore[operator]
        adv = advantages(roll, cfg)
        mean, std, n = normaliser([adv.moments()])
        pol.net.zero_grad(set_to_none=True)
        parts = backward(pol, roll, adv, cfg, mean, std, n)
        assert ("is_weight" in parts) == (version > 2)
        return [p.grad.clone() for p in pol.net.parameters() if p.grad is not None]

    plain = grads(None, 2)
    for shift, version, scale in ((None, 3, 1.0), (np.log(2), 3, 0.5), (-np.log(2), 3, 1.0),
                                  (np.log(2), 2, 1.0)):
        for a, b in zip(grads(shift, version), plain, strict=True):
            torch.testing.assert_close(a, scale * b, rtol=1e-3, atol=1e-7)


def test_bad_weights_are_rejected_and_leave_the_policy_unchanged() -> None:
    pol = make_policy("commattn", SMALL)
    before = {k: v.clone() for k, v in pol.net.state_dict().items()}
    good = weights_of(pol, 3)
    wrong_policy = weights_of(make_policy("vain", SMALL), 4)
    wrong_shape = Weights(good.policy, 5, good.model, dict(good.tensors))
    first = next(iter(wrong_shape.tensors))
    wrong_shape.tensors[first] = np.zeros((2, 2), np.float32)
    wrong_model = Weights(good.policy, 6, {**good.model, "state": 7}, good.tensors)
    nan = Weights(good.policy, 7, good.model, {k: v * np.nan for k, v in good.tensors.items()})
    for w, why in ((wrong_policy, "for 'vain'"), (wrong_shape, "shape"),
                   (wrong_model, "another commattn network"), (nan, "not finite")):
        with pytest.raises(BadMessage, match=why) as err:
            adopt(pol, Weights.unpack(w.pack()))
        assert "\n" not in str(err.value)
    for k, v in pol.net.state_dict().items():
        assert torch.equal(v, before[k])
    with pytest.raises(BadMessage):
        Weights.unpack(b"\x93\x01\x09\x00")


def _listening(hub: str, timeout: float = 60.0) -> None:
    import socket

    host, port = hub.removeprefix("tcp/").rsplit(":", 1)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with socket.create_connection((host, int(port)), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"nothing listens on {hub}")


def _hub(run_id: str, timeout: float = 60.0) -> str:
    """The hub endpoint a `swarm run` notes in its registry, once it listens."""
    from swarm.common.spawn import registry as _registry

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            hub = json.loads(_registry(run_id).read_text())["hub"]
        except (OSError, ValueError, KeyError):
            time.sleep(0.05)
            continue
        _listening(hub, max(deadline - time.monotonic(), 0.1))
        return hub
    raise TimeoutError("no registry entry")


@pytest.mark.procs
@pytest.mark.parametrize("algo", ["ppo"])  # (REINFORCE: the lockstep twin below, 3 updates)
def test_learner_update_from_the_swarm_equals_the_batched_update(tmp_path: Path,
                                                                 algo: str) -> None:
    """`swarm run --train`: the learner's first update from the robots' records equals the
    batched trainer's update on the same episodes (same seed, initial weights, no faults), with
    PPO (whose ratios use the log-probabilities robots recorded; the paper's REINFORCE is
    checked over three updates by `test_lockstep_field_training_is_its_batched_twin`)."""
    cfg = dataclasses.replace(SMALL, horizon=16)  # a small world: the same code paths, faster
    init = initial(tmp_path, cfg, seed=1)
    out = tmp_path / "learner"
    ppo = ["--train-algo", "ppo", "--train-ppo-epochs", "2"] if algo == "ppo" else []
    r = swarm("run", "--train", "--headless", "--config", str(world_toml(tmp_path, cfg)),
              "--policy", "commattn", "--checkpoint", str(init), "--episodes", "4",
              "--train-batch", "4", "--seed", "6",
              "--learner-out", str(out), "--run-id", "geq", "--json", str(tmp_path / "r.json"),
              "--tick-timeout", "10", *ppo)  # no faults: a long deadline changes nothing but load
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp_path / "r.json").read_text())
    learner = res["learner"]
    assert learner["version"] == 1 and learner["episodes"] == 4, json.dumps(learner)
    assert res["learner"]["incomplete"] == 0 and res["learner"]["bad"] == 0
    field = load_checkpoint(out / "checkpoint.pt")
    assert field["learner"]["version"] == 1
    pol = make_policy("commattn", cfg, checkpoint=init)
    roll = collect(pol, cfg, 6, np.arange(4))
    assert np.array_equal(np.array(res["actions"]), np.stack(roll.actions, 1))
    tc = TrainConfig(batch=4, algo=algo, **({"ppo_epochs": 2} if algo == "ppo" else {}))
    assert field["learner"]["train"]["algo"] == algo
    update(pol, torch.optim.Adam(pol.net.parameters(), lr=tc.lr), roll, tc)
    for k, v in pol.net.state_dict().items():
        # one Adam step moves a weight by up to lr (3e-3): 1e-5 is 0.3% of it (float noise in a
        # near-zero gradient can move a weight by ~1e-6)
        torch.testing.assert_close(field["state_dict"][k], v, rtol=1e-4, atol=1e-5)
    row = next(csv.DictReader((out / "curve.csv").open()))
    assert float(row["elratio"]) == pytest.approx(float(roll.metrics.elratio.mean()))
    line = json.loads((out / "log.jsonl").read_text().splitlines()[0])  # names its estimator
    assert line["kind"] == "update" and line["algo"] == algo and line["version"] == 1


@pytest.mark.procs
def test_lockstep_field_training_is_its_batched_twin(tmp_path: Path) -> None:
    """`swarm run --train --train-sync`: every episode is played with the weights of every
    update before it, so the whole run is the batched trainer's loop (collect a batch with the
    current weights, update, repeat) on the same seed: the same actions in every episode, the
    same final weights (float tolerance), nothing stale; the world held each episode for the
    learner and none timed out."""
    init = initial(tmp_path, SMALL, seed=1)
    out = tmp_path / "learner"
    r = swarm("run", "--train", "--train-sync", "--headless", "--config",
              str(world_toml(tmp_path, SMALL)), "--policy", "commattn", "--checkpoint", str(init),
              "--episodes", "12", "--train-batch", "4", "--seed", "6", "--learner-out", str(out),
              "--run-id", "twin", "--json", str(tmp_path / "r.json"))
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["train_sync"]["timeouts"] == 0 and res["train_sync"]["waits"] == 12, res
    learner = res["learner"]
    assert learner["version"] == 3 and learner["stale_used"] == learner["stale_dropped"] == 0
    assert all(st["weights_late"] == 0 for st in res["robot_status"].values())
    # each robot's counts are its final ones (they come after the learner's stop, not before)
    assert all(st["final"] for st in res["robot_status"].values()), res["robot_status"]
    pol = make_policy("commattn", SMALL, checkpoint=init)
    tc = TrainConfig(batch=4)
    opt = torch.optim.Adam(pol.net.parameters(), lr=tc.lr)
    acts = []
    for b in range(3):
        roll = collect(pol, SMALL, 6, np.arange(4 * b, 4 * b + 4))
        acts.append(np.stack(roll.actions, 1))
        update(pol, opt, roll, tc)
    assert np.array_equal(np.array(res["actions"]), np.concatenate(acts))
    field = load_checkpoint(out / "checkpoint.pt")
    for k, v in pol.net.state_dict().items():
        torch.testing.assert_close(field["state_dict"][k], v, rtol=1e-4, atol=1e-5)


def test_learner_gate_checks_the_status_and_waits_for_every_earlier_episode() -> None:
    """The world's view of its learner (lockstep): a status record out of range is refused
    whole; an episode waits until every earlier one is settled and no update is due."""
    gate = LearnerGate(first_episode=5)
    ok = {"version": 2, "last_closed": -1, "pending": 0, "update_due": False}
    for bad in ({"version": -1}, {"version": "2"}, {"last_closed": -2}, {"pending": True},
                {"update_due": 1}, {"version": 2**63}, {"curve": "abc"}, {"curve": [1, "x"]},
                {"accounting": {"trained": -1}}, {"last": {"loss": "nan"}}):
        with pytest.raises(BadMessage):
            gate.offer({**ok, **bad})
    assert gate.version is None and gate.version_for(5) is None
    gate.offer(ok)
    assert gate.version_for(5) == 2 and gate.version_for(6) is None  # 5 not settled yet
    gate.offer({**ok, "last_closed": 5, "pending": 1})
    assert gate.version_for(6) is None  # an episode still joining
    gate.offer({**ok, "last_closed": 5, "update_due": True})
    assert gate.version_for(6) is None
    gate.offer({**ok, "version": 3, "last_closed": 5})
    gate.offer(ok)  # an older record arriving late changes nothing
    assert gate.version_for(6) == 3


@pytest.mark.procs
def test_weights_hot_swap_only_at_episode_boundaries(tmp_path: Path) -> None:
    """Robots tag every tick with the weights version they acted with: within an episode it
    never changes, across episodes it follows the learner; bad weights put on the learner's key
    mid-run are rejected by every robot and counted, and the run completes."""
    run_id = "hswap"
    cfg = world_toml(tmp_path, SMALL, "lr = 0.01")
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--train", "--headless", "--config", str(cfg),
         "--policy", "commattn", "--episodes", "30", "--train-batch", "2", "--seed", "2",
         "--run-id", run_id, "--learner-out", str(tmp_path / "l"), "--json",
         str(tmp_path / "r.json"), "--tick-timeout", "5"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    raw: list[bytes] = []
    try:
        opts = ZenohOptions(mode="client", connect=[_hub(run_id)])
        keys = Keys(run_id)
        with zenoh.open(opts.to_config()) as session:
            sub = session.declare_subscriber(keys.rollout("*"),
                                             lambda s: raw.append(s.payload.to_bytes()))
            pol = make_policy("vain", SMALL)
            deadline = time.monotonic() + 60
            while not raw and time.monotonic() < deadline:  # the robots are acting
                time.sleep(0.05)
            session.put(keys.weights, weights_of(pol, 1000).pack())  # another policy's weights
            proc.wait(timeout=240)
            sub.undeclare()
        assert proc.returncode == 0, proc.stderr.read().decode()[-2000:] if proc.stderr else ""
    finally:
        if proc.poll() is None:
            proc.kill()
    res = json.loads((tmp_path / "r.json").read_text())
    # fresh weights (no --checkpoint): none named (UA pass 59: the temp folder's initial.pt,
    # removed with the folder)
    assert res["completed"] == 30 and res["checkpoint"] is None
    # its learner's checkpoints record the user's command, not the spawned one naming temp files
    assert load_checkpoint(tmp_path / "l" / "checkpoint.pt")["meta"]["command"] == res["command"]
    rollouts = [RobotRollout.unpack(b, SMALL) for b in raw]
    by_ep: dict[int, set[int]] = {}
    for rr in rollouts:
        versions = {t[6] for t in rr.ticks}
        assert len(versions) == 1, (rr.ep, rr.robot, versions)  # never mid-episode
        by_ep.setdefault(rr.ep, set()).update(versions)
    eps = sorted(by_ep)
    assert len(eps) >= 20
    firsts = [min(by_ep[e]) for e in eps]
    assert firsts == sorted(firsts) and firsts[0] == 0 and max(firsts) >= 2
    assert max(max(v) for v in by_ep.values()) <= res["learner"]["version"]
    assert all(r["weights_bad"] >= 1 for r in res["robot_status"].values())
    st = res["learner"]
    assert st["version"] >= 3, st
    # every episode is accounted for: used, or dropped as too stale (robots race ahead of a
    # learner that takes longer per update than the swarm per episode)
    assert st["episodes"] + st["stale_dropped"] + st["incomplete"] == 30, st
    assert st["incomplete"] == 0 and st["bad"] == 0, st


@pytest.fixture(scope="module")
def worker_learners(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """One rollout worker (`--batch 2`) fed to three learners of its run in turn, for the two
    tests that judge what each step showed: the first (OUT l) SIGKILLed once it published
    version 3, a second worker of the first one's id started meanwhile; the same learner again
    with `--resume` until it published 2 more versions, then stopped by Ctrl-C; a fresh learner
    (new OUT b) in its place, until it writes a checkpoint. The worker is then stopped by Ctrl-C
    and started again for one batch. (One run for both tests: each started a learner and a
    worker of its own.)"""
    tmp = tmp_path_factory.mktemp("workers")
    hub = f"tcp/127.0.0.1:{free_port()}"
    out, fresh = tmp / "l", tmp / "b"
    cfg = world_toml(tmp, SMALL)

    def learner(to: Path, log: str, *more: str) -> subprocess.Popen[bytes]:
        return spawn("learner", "--run-id", "dur", "--config", str(cfg), "--out", str(to),
                     "--batch", "4", "--zenoh-mode", "router", "--listen", hub, "--policy",
                     "vain", *more, log=tmp / log)

    got: dict[str, Any] = {"tmp": tmp, "out": out, "fresh": fresh}
    seen: list[int] = []
    lock = threading.Lock()

    def on_weights(s: zenoh.Sample) -> None:
        with lock:
            seen.append(Weights.unpack(s.payload.to_bytes()).version)

    procs: list[subprocess.Popen[Any]] = [learner(out, "l1.log")]
    try:
        _listening(hub)
        worker = subprocess.Popen(
            [sys.executable, "-m", "swarm.cli", "rollout-worker", "--run-id", "dur", "--connect",
             hub, "--zenoh-mode", "client", "--batch", "2"], cwd=ROOT, stdout=subprocess.PIPE,
            stderr=open(tmp / "w.log", "w"), text=True)  # noqa: SIM115
        procs.append(worker)
        opts = ZenohOptions(mode="client", connect=[hub])
        with zenoh.open(opts.to_config()) as session:
            sub = session.declare_subscriber(Keys("dur").weights, on_weights)
            deadline = time.monotonic() + 90
            dup = None  # a second worker of its id would play the same episodes: refused
            while time.monotonic() < deadline and max(seen, default=0) < 3:
                if max(seen, default=0) >= 1 and dup is None:  # (an update: the worker is up)
                    dup = subprocess.Popen(
                        [sys.executable, "-m", "swarm.cli", "rollout-worker", "--run-id", "dur",
                         "--connect", hub, "--zenoh-mode", "client"], cwd=ROOT,
                        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                time.sleep(0.05)
            if dup is not None:
                got["dup"] = (dup.communicate(timeout=60)[1], dup.returncode)
            os.kill(procs[0].pid, signal.SIGKILL)
            procs[0].wait(timeout=10)
            with lock:
                got["published"] = max(seen, default=0)
            sub.undeclare()
        got["killed"] = load_checkpoint(out / "checkpoint.pt")
        time.sleep(1.0)
        got["worker_on"] = worker.poll() is None  # (the worker without its learner)
        procs[0] = learner(out, "l2.log", "--resume")
        seen.clear()
        _listening(hub)
        with zenoh.open(opts.to_config()) as session:
            sub = session.declare_subscriber(Keys("dur").weights, on_weights)
            deadline = time.monotonic() + 90
            got["target"] = target = got["killed"]["learner"]["version"] + 2
            while time.monotonic() < deadline and max(seen, default=0) < target:
                time.sleep(0.05)
            sub.undeclare()
        with lock:
            got["resumed"] = list(seen)
        procs[0].send_signal(signal.SIGINT)  # the resumed learner goes; a fresh one replaces it
        got["stopped"] = procs[0].wait(timeout=30)
        got["stopped_version"] = load_checkpoint(out / "checkpoint.pt")["learner"]["version"]
        procs[0] = learner(fresh, "b.log")
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (fresh / "checkpoint.pt").exists():
            time.sleep(0.05)
        got["worker_on_fresh"] = worker.poll() is None  # (the worker never stopped)
        worker.send_signal(signal.SIGINT)
        got["summary"] = worker.communicate(timeout=60)[0], worker.returncode
        # the same worker again goes on after the last episode the learner heard from it
        got["again"] = swarm("rollout-worker", "--run-id", "dur", "--connect", hub,
                             "--zenoh-mode", "client", "--batch", "2", "--max-batches", "1",
                             timeout=120)
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
    return got


@pytest.mark.procs
def test_learner_sigkill_and_resume_with_a_rollout_worker(worker_learners: dict[str, Any]
                                                          ) -> None:
    """A learner fed by a rollout worker is SIGKILLed mid-training: every version it had
    published is in its checkpoint; `--resume` continues from it (curve and versions carry on),
    the worker keeps going meanwhile and the resumed learner keeps learning. A second worker of
    the first one's id is refused. (The first two learners of `worker_learners`.)"""
    w = worker_learners
    assert "dup" in w  # (the second worker was started)
    err, code = w["dup"]
    assert code == 2 and err.strip().splitlines()[-1] == (
        "swarm: error: rollout worker 0 of run dur is running already (its liveliness "
        "token is up)"), err
    ck = w["killed"]
    assert ck["learner"]["version"] >= w["published"] >= 3  # nothing acknowledged was lost
    assert w["worker_on"]  # the worker goes on without its learner
    seen, target = w["resumed"], w["target"]
    assert max(seen) >= target, (seen, (w["tmp"] / "l2.log").read_text()[-800:])
    rows = list(csv.DictReader((w["out"] / "curve.csv").open()))
    updates = [int(r["update"]) for r in rows]
    assert updates == sorted(set(updates)) and updates[0] == 1  # no row repeated after resume
    elapsed = [float(r["elapsed_s"]) for r in rows]  # the run's time: it goes on across resume
    assert elapsed == sorted(elapsed), elapsed


@pytest.mark.procs
def test_short_field_training_improves_mean_reward(tmp_path: Path) -> None:
    """`swarm run --train` from fresh weights on a tiny static map: the learner's final weights
    earn a higher mean reward than the initial ones on 400 held-out sampled episodes.

    Lockstep (`--train-sync`): the run is a function of its seed, so this gain is one figure,
    -72.1 to -62.0 (+10.1 after these 120 episodes; +10.4 after 240, +14.0 after 480, +7.1
    after 64), on every run, loaded machine or not.
    (Asynchronous, it was not: which episodes landed in which update, and how stale, depended
    on timing; six runs gave +11 to +18 and one CI run beside another test run +1.8.) Judged
    by a batched evaluation of both weight sets on the same episodes, not by the run's own
    per-update curve."""
    toml = tmp_path / "tiny.toml"
    world = dict(height=6, width=6, n_static=3, n_dynamic=0, dynamic=False, n_robots=2,
                 horizon=8, vision=3, comm_range=float("inf"), recent_len=4)
    toml.write_text("[world]\nheight = 6\nwidth = 6\nn_static = 3\nn_dynamic = 0\n"
                    "dynamic = false\nn_robots = 2\nhorizon = 8\nvision = 3\n"
                    "comm_range = inf\nrecent_len = 4\n"
                    "[train]\nlr = 0.003\ngamma = 0.9\nent_coef = 0.01\n"
                    "[learner]\nmax_staleness = 3\n")
    out = tmp_path / "l"
    r = swarm("run", "--train", "--train-sync", "--headless", "--config", str(toml), "--policy",
              "commattn", "--episodes", "120", "--train-batch", "8", "--seed", "1",
              "--learner-out", str(out), "--run-id", "tinyfield", "--json",
              str(tmp_path / "r.json"), timeout=400)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = list(csv.DictReader((out / "curve.csv").open()))
    assert len(rows) == 15, len(rows)  # lockstep: every episode in an update, none stale
    cfg = WorldConfig(**world)  # type: ignore[arg-type]
    torch.manual_seed(1)  # the run's initial weights: torch seed = run seed
    before = make_policy("commattn", cfg)
    after = make_policy("commattn", cfg, checkpoint=out / "checkpoint.pt")
    assert load_checkpoint(out / "checkpoint.pt")["learner"]["version"] == len(rows)
    reward = [evaluate(cfg, p, seed=12345, n_episodes=400, greedy=False).reward.mean()
              for p in (before, after)]
    assert reward[1] > reward[0] + 6, reward


@pytest.mark.procs
def test_rollout_loss_drops_records_and_the_learner_counts_incomplete_episodes(
        tmp_path: Path) -> None:
    """A fault on the rollout traffic: robots drop their episode records with the seeded
    probability; the learner drops those episodes as incomplete (counted), never trains on them."""
    toml = world_toml(tmp_path, SMALL)
    toml.write_text(toml.read_text() + "[learner]\njoin_timeout = 2\n")  # (default 5 s)
    r = swarm("run", "--train", "--headless", "--config", str(toml), "--policy", "vain",
              "--episodes", "12", "--train-batch", "2", "--rollout-loss", "0.5", "--seed", "4",
              "--run-id", "rloss", "--learner-out", str(tmp_path / "l"),
              "--json", str(tmp_path / "r.json"))
    assert r.returncode == 0, r.stderr[-2000:]
    st = json.loads((tmp_path / "r.json").read_text())["learner"]
    from world.noise import uniform

    lost = {(ep, i) for ep in range(12) for i in range(SMALL.n_robots)
            if uniform(4, ep, 0, i, 1, stream=7)[0] < 0.5}
    hit = {ep for ep, _ in lost}
    assert st["incomplete"] == len(hit) and st["episodes"] + st["stale_dropped"] == 12 - len(hit)
    assert 0 < len(hit) < 12


def _hand_run(tmp_path: Path, run_id: str) -> tuple[str, Path, list[subprocess.Popen[bytes]]]:
    """A lockstep training run started by hand (README: `swarm world` and `swarm robot`s): its
    hub, its config file (a team of 2 on the SMALL map) and its processes."""
    hub = f"tcp/127.0.0.1:{free_port()}"
    cfg = dataclasses.replace(SMALL, n_robots=2)
    conf = world_toml(tmp_path, cfg)
    conf.write_text(conf.read_text() + "[run]\ntrain = true\ntrain_sync = true\n"
                    f"checkpoint = \"{initial(tmp_path, cfg)}\"\n")
    procs = [spawn("world", "--run-id", run_id, "--config", str(conf), "--episodes", "4",
                   "--listen", hub, "--json", str(tmp_path / "world.json"),
                   log=tmp_path / "world.log")]
    procs += [spawn("robot", "--id", str(i), "--run-id", run_id, "--connect", hub,
                    log=tmp_path / f"robot{i}.log") for i in range(2)]
    return hub, conf, procs


@pytest.mark.procs
def test_a_learner_by_hand_ends_with_its_run(tmp_path: Path) -> None:
    """`swarm learner` started by hand beside a world and its robots ends when the run ends
    (the world's end record), as its banner says, with its checkpoint written and one line
    saying where; it ran on until stopped."""
    hub, conf, procs = _hand_run(tmp_path, "handend")
    out = tmp_path / "l"
    learner = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "learner", "--run-id", "handend", "--config",
         str(conf), "--out", str(out), "--batch", "2", "--connect", hub, "--zenoh-mode",
         "client"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert procs[0].wait(timeout=120) == 0, (tmp_path / "world.log").read_text()[-1500:]
        _, err = learner.communicate(timeout=60)  # (without the fix: it never ended)
        assert learner.returncode == 0, err[-1500:]
        assert f"run handend ended (the world's end record); version 2 in {out}" in err, err
        # the world's token going, still queued at the end, is no rollout (it was read as one:
        # "dropped bad payload on swarm/handend/alive/world", bad 1, in most runs)
        assert "dropped bad payload" not in err, err
        ck = load_checkpoint(out / "checkpoint.pt")
        assert ck["learner"]["version"] == 2
        # the command that made it, whole (it said 'swarm learner' and no argument)
        assert ck["meta"]["command"] == shlex.join(["swarm", *learner.args[3:]]), ck["meta"]
        assert json.loads((tmp_path / "world.json").read_text())["completed"] == 4
    finally:
        for p in (*procs, learner):
            if p.poll() is None:
                p.kill()


@pytest.mark.procs
def test_a_second_learner_of_a_run_is_refused_in_one_line(tmp_path: Path) -> None:
    """Two learners of one run would each publish weights, robots adopting whichever came last:
    one whose run's learner token is up stops before it writes anything (exit 2)."""
    hub = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(ZenohOptions(listen=[hub]).to_config()) as session:
        token = session.liveliness().declare_token(Keys("twolearn").alive_learner)
        r = swarm("learner", "--run-id", "twolearn", "--config", str(world_toml(tmp_path, SMALL)),
                  "--out", str(tmp_path / "l"), "--connect", hub, timeout=60)
        token.undeclare()
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines()[-1] == ("swarm: error: a learner of run twolearn is "
                                                 "running already (its liveliness token is up)")
    assert not (tmp_path / "l").exists()


@pytest.mark.procs
def test_a_learner_by_hand_of_another_world_is_one_error(tmp_path: Path) -> None:
    """A hand learner whose world differs from its run's (here: no team size given, so 3
    robots, while the run has 2) learns the run's record from the world and stops with one
    line naming the difference, exit 2 (it dropped every episode with a warning, never
    trained, and a lockstep world waited on it)."""
    hub, _, procs = _hand_run(tmp_path, "handbad")
    (tmp_path / "mine").mkdir()
    learner = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "learner", "--run-id", "handbad", "--config",
         str(world_toml(tmp_path / "mine", SMALL)), "--out", str(tmp_path / "l"), "--batch", "2",
         "--connect", hub, "--zenoh-mode", "client"], cwd=ROOT, stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True)
    try:
        _, err = learner.communicate(timeout=120)
        assert learner.returncode == 2, err[-1500:]
        last = err.strip().splitlines()[-1]
        assert last.startswith("swarm: error: this learner does not fit run handbad: n_robots "
                               "3 here, 2 in the run"), err
        assert "dropped bad payload" not in err
    finally:
        for p in (*procs, learner):
            if p.poll() is None:
                p.kill()


@pytest.mark.procs
def test_a_training_run_says_where_its_weights_went(tmp_path: Path) -> None:
    """`swarm run --train` with neither --learner-out nor --json ends with one line naming the
    trained checkpoint (in the run's temp folder, kept): it was said nowhere."""
    cfg = dataclasses.replace(SMALL, n_robots=2)
    r = swarm("run", "--train", "--train-sync", "--headless", "--config",
              str(world_toml(tmp_path, cfg)), "--policy", "commattn", "--checkpoint",
              str(initial(tmp_path, cfg)), "--episodes", "4", "--train-batch", "2", "--seed", "1",
              env={"TMPDIR": str(tmp_path)})
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])["result"]
    ckpt = Path(res["learner"]["out"]) / "checkpoint.pt"
    assert ckpt.is_relative_to(tmp_path) and load_checkpoint(ckpt)["learner"]["version"] == 2
    said = [x for x in r.stderr.splitlines() if "trained weights" in x]
    assert said == [f"swarm: trained weights (version 2): {ckpt}"], r.stderr[-2000:]


def _processes() -> list[tuple[int, list[str]]]:
    """(pid, argv) of every process readable now (one that ended meanwhile is left out)."""
    found = []
    for p in Path("/proc").iterdir():
        try:
            if p.name.isdigit():
                found.append((int(p.name), (p / "cmdline").read_bytes().decode(
                    errors="replace").split("\0")))
        except OSError:
            pass
    return found


@pytest.mark.procs
@pytest.mark.parametrize("kill", ["learner", "world", "interrupt"])
def test_a_training_run_that_ends_early_names_its_checkpoint_and_writes_its_json(
        tmp_path: Path, kill: str) -> None:
    """A SIGKILLed field learner ended `swarm run --train` with "the learner failed: exit code
    -9" and no result JSON: an older run's file at the --json path stood as if it were this
    run's, and nothing said where the trained weights were; a dead world, or Ctrl-C, did the
    same (UA passes 78-79). Now the checkpoint is named from the file (its version and trained
    episodes, which the learner's last status may lag: the world routes it), and --json holds
    the error and what the run had done."""
    cfg = dataclasses.replace(SMALL, n_robots=2)
    out, res, learner = tmp_path / "r.json", tmp_path / "L", tmp_path / "L" / "checkpoint.pt"
    out.write_text('{"an": "older run"}')
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--train", "--train-sync", "--headless",
         "--config", str(world_toml(tmp_path, cfg)), "--policy", "commattn", "--checkpoint",
         str(initial(tmp_path, cfg)), "--episodes", "500", "--train-batch", "2", "--run-id",
         f"early{kill}", "--learner-out", str(res), "--json", str(out)], cwd=ROOT, text=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env={**os.environ,
                                                                "TMPDIR": str(tmp_path)})
    try:
        deadline = time.monotonic() + 120  # (a failsafe, not a measurement)
        while not learner.is_file() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        if kill == "interrupt":
            proc.send_signal(signal.SIGINT)
        else:  # (the run's child: `swarm.cli learner ... --out L` or `world ... --run-id`)
            pids = [pid for pid, args in _processes() if kill in args and "--spec" in args
                    and f"early{kill}" in args]
            assert len(pids) == 1, pids
            os.kill(pids[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    lines = err.strip().splitlines()
    said = {"learner": "the learner failed: killed by SIGKILL",
            "world": "world ended without a result (exit code -9", "interrupt": "interrupted"}
    assert proc.returncode == (130 if kill == "interrupt" else 1), err
    assert said[kill] in lines[-1], err
    saved = load_checkpoint(learner)["learner"]
    named = [x for x in lines if "the learner's last checkpoint" in x]
    assert named == [f"swarm: the learner's last checkpoint: {learner} (version "
                     f"{saved['version']}, {saved['counters']['trained']} episodes trained)"], err
    got = json.loads(out.read_text())
    assert got["error"] in lines[-1] or got["error"] == "interrupted", (got["error"], err)
    assert got["run"]["train"] is True and got["learner"]["checkpoint"] == {
        "path": str(learner), "version": saved["version"],
        "trained": saved["counters"]["trained"]}, got
    acc = got["learner"]["accounting"]  # (from its last status, which may lag the file)
    assert acc["played"] == acc["unaccounted"] + sum(
        acc.get(k, 0) for k in ("trained", "pending", "stale_dropped", "incomplete", "rejected"))
    assert saved["counters"]["trained"] >= 2, got


def test_episodes_no_learner_counter_holds_are_a_warning_line(
        capsys: pytest.CaptureFixture[str]) -> None:
    """A learner stopped (SIGSTOP) for 12 s mid-run lost 12 of 40 episodes: counted in
    `unaccounted`, but the run ended with exit 0 and not a word (UA pass 79)."""
    from swarm.procs.learning.supervised import learner_result

    status = {"accounting": {"received": 28, "trained": 28}}
    assert learner_result(status, 40, "L")["accounting"]["unaccounted"] == 12
    assert capsys.readouterr().err == ""  # (the dashboard's and JSON's reads say nothing)
    assert learner_result(status, 40, "L", warn=True)["accounting"]["unaccounted"] == 12
    assert capsys.readouterr().err == ("swarm: warning: 12 of the 40 episodes played reached no "
                                       "learner counter (unaccounted: the learner never heard "
                                       "them, or its last status did not come)\n")


def test_no_update_says_what_became_of_the_episodes_that_came() -> None:
    """It said "fewer than 3 episodes reached it" when 8 had, 7 of them incomplete."""
    from swarm.procs.learning.supervised import trained_line

    learner = {"out": "/nonexistent/learner", "accounting": {
        "received": 8, "trained": 0, "pending": 1, "incomplete": 7, "stale_dropped": 0}}
    assert trained_line(learner, 3) == (
        "swarm: the learner made no update (a batch is 3 usable episodes; it received 8: 1 "
        "pending, 7 incomplete): no checkpoint in /nonexistent/learner")
    assert "it received 0)" in trained_line({"out": "/nonexistent"}, 3)


@pytest.mark.procs
def test_a_rollout_worker_follows_a_fresh_learner_that_replaced_its_own(
        worker_learners: dict[str, Any]) -> None:
    """A learner fed by a rollout worker is stopped and a fresh one (new --out) takes its
    place: the worker kept the old one's weights, the new one rejected every episode played
    with them ("newer than its own v0") and never trained (UA pass). The worker now asks a
    learner that comes up for its weights, so the new learner trains. Both end by Ctrl-C, their
    usual end, and say what they did (they said nothing: the learner where its checkpoint is,
    the worker its summary). The same worker started again goes on where the new learner has
    it. (The old learner: the resumed one of `worker_learners`, at version 5 or later.)"""
    w = worker_learners
    a = w["out"] / "checkpoint.pt"
    assert a.exists(), (w["tmp"] / "l2.log").read_text()
    assert w["stopped"] == 0  # the old learner went by Ctrl-C
    version = w["stopped_version"]
    assert (w["tmp"] / "l2.log").read_text().strip().splitlines()[-1] == (
        f"swarm learner: stopped; version {version} in {a}")
    b = w["fresh"] / "checkpoint.pt"
    # (without the fix: no checkpoint, every worker episode rejected)
    assert b.exists(), (w["tmp"] / "b.log").read_text()
    assert load_checkpoint(b)["learner"]["version"] >= 1
    assert w["worker_on_fresh"]  # the worker never stopped
    out, code = w["summary"]
    summary = json.loads(out.strip().splitlines()[-1])
    assert code == 0 and summary["interrupted"] and summary["episodes"] > 0
    # the same worker again goes on after the last episode the learner heard from it (it
    # replayed its seed's episodes from 0)
    again = w["again"]
    assert again.returncode == 0, again.stderr[-1500:]
    second = json.loads(again.stdout.strip().splitlines()[-1])
    assert (second["first_episode"], second["episodes"]) == (summary["episodes"], 2), second
