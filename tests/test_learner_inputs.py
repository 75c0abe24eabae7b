"""What the learner, rollout workers and the rollout bench refuse, and how a learner resumes:
bad values are one line and exit 2 before anything is spawned or written (real `swarm`
subprocesses); a resumed learner holds its flags against its checkpoint and shows its curve
(a real learner on real Zenoh on loopback)."""

from __future__ import annotations

import dataclasses
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zenoh
from conftest import ROOT, swarm, swarm_here

from swarm.common.spawn import wait_port
from swarm.learn.config import TrainConfig
from swarm.net.keys import Keys
from swarm.net.messages import K_LSTATUS, BadMessage, unpack_record
from swarm.net.zconfig import ZenohOptions, free_port, open_session
from world.config import ConfigError, WorldConfig, from_dict

SMALL = WorldConfig(height=8, width=8, n_static=6, n_dynamic=4, n_robots=3, horizon=8,
                    add_every=2, vision=3, comm_range=4.0, recent_len=4)
WORKER0 = TrainConfig().train_seed_offset + TrainConfig().seed + 1
"""The seed rollout worker 0 plays (a learner drops a worker episode of any other seed)."""

BAD = [  # (argv, what the one line must say); {tmp}/o must not exist afterwards
    (["learner", "--out", "{tmp}/o", "--ppo-epochs", "3"], "ppo_epochs = 3 only applies"),
    (["learner", "--out", "{tmp}/o", "--algo", "reinforce", "--ppo-epochs", "2"], "algo ppo"),
    (["run", "--train", "--headless", "--train-ppo-epochs", "3"],
     "ppo_epochs = 3 only applies"),
    (["train", "--out", "{tmp}/o", "--ppo-epochs", "3"], "ppo_epochs = 3 only applies"),
    (["train", "--out", "{tmp}/o", "--gae-lambda", "0.5"], "gae_lambda = 0.5 only applies"),
    (["learner", "--out", "{tmp}/o", "--max-staleness", "-1"], "max_staleness"),
    (["learner", "--out", "{tmp}/o", "--join-timeout", "-1"], "join_timeout"),
    (["learner", "--out", "{tmp}/o", "--join-timeout", "nan"], "join_timeout"),
    (["learner", "--out", "{tmp}/o", "--config", "{tmp}/bad.toml"], "max_staleness"),
    (["learner", "--out", "{tmp}/o", "--config", "{tmp}/bad2.toml"], "join_timeout"),
    (["run", "--train", "--headless", "--config", "{tmp}/bad.toml"],
     "max_staleness"),
    (["learner", "--out", "{tmp}/o", "--policy", "nearest-frontier"], "needs a learned policy"),
    (["learner", "--out", "{tmp}/o", "--gather-only", "--resume"], "nothing to --resume"),
    (["learner", "--out", "{tmp}/o", "--policy", "nope"], "unknown policy"),
    (["learner", "--out", "{tmp}/o", "--checkpoint", "{tmp}"], "is a directory"),
    (["eval", "--policy", "commattn", "--checkpoint", "{tmp}", "--episodes", "1"],
     "is a directory"),
    (["rollout-worker", "--run-id", "x", "--worker-id", "99999999999999999999"], "--worker-id"),
    (["rollout-worker", "--run-id", "x", "--worker-id", "-1"], "--worker-id"),
    # (its key names it, as six digits at most: a larger id's episodes were all dropped)
    (["rollout-worker", "--run-id", "x", "--worker-id", "1000000"], "in [0, 999999]"),
    (["rollout-worker", "--run-id", "x", "--wait", "nan"], "--wait"),
    (["rollout-worker", "--run-id", "x", "--wait", "-1"], "--wait"),
    (["rollout-worker", "--run-id", "x", "--max-batches", "-1"], "--max-batches"),
    (["rollout-worker", "--run-id", "x", "--batch", "100000"], "--batch"),
    (["rollout-worker", "--run-id", "", "--wait", "0.5"], "bad run id ''"),  # (no banner)
    (["learner", "--run-id", "x", "--out", " "], "--out wants a directory, got an empty name"),
    (["bench", "rollout", "--policy", "nearest-frontier", "--workers", "1"],
     "needs a learned policy"),
]


@pytest.mark.parametrize("args, says", BAD, ids=lambda a: " ".join(a)[:48] if isinstance(a, list)
                         else "")
def test_a_bad_learning_input_is_one_line_exit_2_and_leaves_nothing(
        tmp_path: Path, args: list[str], says: str, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "bad.toml").write_text("[learner]\nmax_staleness = -1\njoin_timeout = -5\n")
    (tmp_path / "bad2.toml").write_text("[learner]\njoin_timeout = -5\n")
    r = swarm_here(*(a.replace("{tmp}", str(tmp_path)) for a in args), capsys=capsys)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, r.stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith("swarm: error: "), r.stderr
    assert says in lines[0], lines[0]
    assert not (tmp_path / "o").exists()  # checked before any folder is made


def test_ppo_settings_need_the_ppo_estimator() -> None:
    """`ppo_epochs` (and GAE's lambda, the clip) do nothing under REINFORCE: refused in the one
    place every entry point builds its TrainConfig; their defaults and PPO itself still pass."""
    TrainConfig()
    TrainConfig(algo="ppo", ppo_epochs=3, gae_lambda=0.9, ppo_clip=0.1)
    for changes in ({"ppo_epochs": 3}, {"ppo_clip": 0.3}, {"gae_lambda": 0.5, "ppo_epochs": 2}):
        with pytest.raises(ConfigError, match="only applies with algo ppo") as err:
            from_dict(TrainConfig, changes, "[train]")
        assert "\n" not in str(err.value)


@pytest.mark.parametrize("field, value", [("max_staleness", -1), ("max_staleness", 1.5),
                                          ("join_timeout", -5.0), ("join_timeout", float("nan")),
                                          ("join_timeout", 0.0), ("status_every", 0.0),
                                          ("status_every", float("inf")), ("seed", -1),
                                          ("seed", 2**40), ("run_id", "a/b"), ("run_id", "")])
def test_learner_config_ranges_are_one_line_errors(field: str, value: object) -> None:
    from swarm.learn.config import LearnerConfig

    with pytest.raises(ConfigError) as err:
        from_dict(LearnerConfig, {field: value}, "[learner]")
    assert "\n" not in str(err.value) and (field in str(err.value) or "run id" in str(err.value))
    LearnerConfig(max_staleness=0, join_timeout=0.5, status_every=0.1, seed=7, run_id="r-1")


# ------------------------------------------------------------------------------ resuming
@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A learner directory after 3 real updates (batch 2, policy vain on SMALL): checkpoint,
    curve.csv with 3 rows, and the world file its CLI resume reads."""
    from swarm.learn.config import LearnerConfig
    from swarm.learn.join import episodes_of
    from swarm.learn.rollout import collect
    from swarm.procs.learning.learner import Learner

    tmp = tmp_path_factory.mktemp("trained")
    fields = ("height", "width", "n_static", "n_dynamic", "n_robots", "horizon", "add_every",
              "vision", "comm_range", "recent_len")
    (tmp / "world.toml").write_text("[world]\n" + "".join(
        f"{k} = {getattr(SMALL, k)}\n" for k in fields))
    learner = Learner(SMALL, LearnerConfig(run_id="resumed", policy="vain", out=str(tmp / "l")),
                      TrainConfig(batch=2, threads=1))
    learner.seed = 0  # (what `run` notes: the run's seed, which `collect` below plays)
    assert not (tmp / "l").exists()  # nothing is written before open_out
    with open_session(ZenohOptions()) as session:
        learner.open_out()
        inbox = learner._declare(session)
        try:
            for u in range(3):
                roll = collect(learner.policy, SMALL, WORKER0, np.arange(2 * u, 2 * u + 2))
                for ep in episodes_of(roll, learner.version):  # (as a rollout worker's)
                    learner.handle("worker", Keys("resumed").worker_episodes(0), ep.pack())
                assert learner.maybe_update()
        finally:
            inbox.close()
            learner.journal.close()
    return tmp


def test_resume_holds_the_given_train_settings_against_the_checkpoint(trained: Path) -> None:
    """A given setting that differs from the checkpoint's is refused, each named; equal ones and
    threads (not the run's math) pass; settings not given keep the checkpoint's."""
    from swarm.learn.config import LearnerConfig
    from swarm.procs.learning.learner import Learner

    lc = LearnerConfig(run_id="resumed", policy="vain", out=str(trained / "l"), resume=True)
    with pytest.raises(ConfigError, match=r"batch = 4 .*lr = 0.5") as err:
        Learner(SMALL, lc, TrainConfig(batch=4, lr=0.5), {"batch", "lr"})
    assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match="batch = 288"):  # None: all of tc is meant
        Learner(SMALL, lc, TrainConfig(threads=1), None)
    kept = Learner(SMALL, lc, TrainConfig(lr=0.5, threads=1), {"threads"})
    assert kept.tc.batch == 2 and kept.tc.lr == TrainConfig().lr and kept.version == 3
    same = Learner(SMALL, lc, TrainConfig(batch=2, threads=2), None)
    assert same.tc.threads == 2 and same.tc.batch == 2


def test_swarm_learner_resume_refuses_new_train_flags(trained: Path) -> None:
    base = ["learner", "--run-id", "resumed", "--config", str(trained / "world.toml"), "--out",
            str(trained / "l"), "--policy", "vain", "--resume"]
    for extra, says in ((["--batch", "4", "--lr", "0.5"], ["batch = 4", "lr = 0.5"]),
                        (["--checkpoint", str(trained / "l" / "checkpoint.pt")],
                         ["--checkpoint"]),  # and another world (it went on with the flags')
                        (["--size", "30x30"], ["on the world it was trained on", "height = 30"]),
                        (["--robots", "5"], [f"n_robots = 5 differs from its {SMALL.n_robots}"]),
                        (["--seed", "5"], ["seed = 5 differs from its 0"])):  # (was taken)
        r = swarm(*base, *extra, timeout=60)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2, r.stderr[-2000:]
        assert len(lines) == 1 and lines[0].startswith("swarm: error: "), r.stderr
        assert all(s in lines[0] for s in says), lines[0]


def test_a_resumed_learner_joins_with_its_runs_seed(trained: Path) -> None:
    """The seed its episodes were joined with is in the checkpoint: a resume without --seed
    goes on with it (it went on with 0 whatever the run's); a checkpoint without one takes the
    given seed, as before."""
    from policies.checkpoint import read_checkpoint
    from swarm.learn.config import held_seed

    state = read_checkpoint(trained / "l" / "checkpoint.pt")["learner"]
    assert state["seed"] == 0 and held_seed(state, None, trained) == 0
    assert held_seed({**state, "seed": 7}, None, trained) == 7
    assert held_seed({**state, "seed": 7}, 7, trained) == 7
    with pytest.raises(ConfigError, match="seed = 3 differs from its 7"):
        held_seed({**state, "seed": 7}, 3, trained)
    old = {k: v for k, v in state.items() if k != "seed"}
    assert held_seed(old, 3, trained) == 3 and held_seed(old, None, trained) == 0


@pytest.mark.procs
def test_a_resumed_learner_shows_its_curve(trained: Path) -> None:
    """`swarm learner --resume`: the status's sparkline (`curve`) and last row come from the
    curve the run wrote before, not from nothing."""
    import csv

    rows = list(csv.DictReader((trained / "l" / "curve.csv").open()))
    assert len(rows) == 3
    out = trained / "copy"  # resume a copy: the other tests read the original
    shutil.copytree(trained / "l", out)
    hub = f"tcp/127.0.0.1:{free_port()}"
    got: list[dict] = []
    lock = threading.Lock()

    def on_status(s: zenoh.Sample) -> None:
        try:
            rec = unpack_record(s.payload.to_bytes(), K_LSTATUS)
        except BadMessage:
            return
        with lock:
            got.append(rec)

    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", "learner", "--run-id",
                             "resumed", "--config", str(trained / "world.toml"), "--out",
                             str(out), "--policy", "vain", "--resume", "--zenoh-mode", "router",
                             "--listen", hub], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
    try:
        wait_port("127.0.0.1", int(hub.rsplit(":", 1)[1]), proc, 60.0, "learner")
        with zenoh.open(ZenohOptions(mode="client", connect=[hub]).to_config()) as session:
            sub = session.declare_subscriber(Keys("resumed").learner_status, on_status)
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and not got and proc.poll() is None:
                time.sleep(0.05)
            sub.undeclare()
    except RuntimeError:
        pass  # (the learner exited: the assertions below show its stderr)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
    assert got, err.decode()[-2000:]
    st = got[0]
    assert st["version"] == 3
    assert st["curve"] == pytest.approx([float(r["elratio"]) for r in rows], abs=1e-5)
    assert st["last"]["elratio"] == pytest.approx(float(rows[-1]["elratio"]), abs=1e-5)
    assert st["last"]["reward"] == pytest.approx(float(rows[-1]["reward"]), rel=1e-5)


def test_a_late_record_of_what_the_stopped_learner_held_is_late_not_a_new_episode(
        trained: Path) -> None:
    """A learner SIGKILLed while it joined swarm episode 7 (one robot's record in) is resumed:
    episode 7 is counted lost once, and a late record of it reaching the resumed learner is a
    late record, not episode 7 received a second time (it opened a new slot and was counted in
    `received` again, then as incomplete); a lockstep world learns that 7 is settled. So too
    when the learner wrote a checkpoint while 7 was joining (the checkpoint names it), and for
    a rollout worker's episodes heard after the checkpoint: a restarted worker goes on after
    them (it was served the checkpoint's next episode and played them again)."""
    from swarm.learn.config import LearnerConfig
    from swarm.learn.join import episodes_of
    from swarm.learn.rollout import collect
    from swarm.procs.learning.learner import Learner
    from swarm.procs.runconfig import RunRecord

    out = trained / "late"  # a copy: the other tests read the original
    shutil.copytree(trained / "l", out)
    lc = LearnerConfig(run_id="resumed", policy="vain", out=str(out), resume=True)

    def resumed() -> Learner:
        learner = Learner(SMALL, lc, TrainConfig(batch=2, threads=1), {"threads"})
        learner.open_out()
        return learner

    first = resumed()
    try:
        assert first._slot(7) is not None and first.accounting()["pending"] == 1
        er = episodes_of(collect(first.policy, SMALL, WORKER0 + 1, np.arange(3, 4)), 0)[0]
        first.handle("worker", Keys("resumed").worker_episodes(1), er.pack())  # worker 1's ep 3
    finally:  # (then SIGKILL: nothing more is written)
        first.journal.close()
    second = resumed()
    try:
        acc = second.accounting()
        assert acc["lost"] == 2 and acc["received"] == first.accounting()["received"], acc
        assert second._slot(7) is None and second.c.late_records == 1
        assert second.accounting() == acc and second.settled.last == 7
        assert RunRecord.unpack(second.record()).workers == {0: 6, 1: 4}  # (0: the fixture's)
        assert second._slot(8) is not None and second.c.received == acc["received"] + 1
        second.save()  # a checkpoint while 8 is joining: it names 8
    finally:  # (SIGKILL again)
        second.journal.close()
    third = resumed()
    try:
        late = third.c.late_records
        assert third._slot(8) is None and third._slot(7) is None
        assert third.c.late_records == late + 2 and third.settled.last == 8
        assert RunRecord.unpack(third.record()).workers == {0: 6, 1: 4}
    finally:
        third.journal.close()


def test_a_resumed_learner_counts_what_its_stopped_self_held(trained: Path) -> None:
    """The episodes a learner heard of after its last checkpoint and never trained on (its
    partial batch) end in a counter when it is killed and resumed: `lost`, once however often
    it is killed before its next update, and the accounting still sums (they were in no
    counter: the checkpoint's counters are its last update's)."""
    from swarm.learn.config import LearnerConfig
    from swarm.learn.join import episodes_of
    from swarm.learn.rollout import collect
    from swarm.net.learning import ACCOUNTING
    from swarm.procs.learning.learner import Learner

    out = trained / "lost"  # a copy: the other tests read the original
    shutil.copytree(trained / "l", out)
    lc = LearnerConfig(run_id="resumed", policy="vain", out=str(out), resume=True)
    made: list[Learner] = []

    def resumed() -> dict[str, int]:
        learner = Learner(SMALL, lc, TrainConfig(batch=2, threads=1), {"threads"})
        learner.open_out()
        made.append(learner)
        return learner.accounting()

    def sums(acc: dict[str, int]) -> int:  # 0: every episode heard of in one counter
        return acc["received"] - sum(acc[k] for k in ACCOUNTING if k != "received")

    try:
        before = resumed()
        assert before["lost"] == 0 and sums(before) == 0
        eps = episodes_of(collect(made[0].policy, SMALL, WORKER0, np.arange(6, 10)),
                          made[0].version)
        made[0].handle("worker", Keys("resumed").worker_episodes(0), eps[0].pack())
        # half a batch, then SIGKILL (nothing more is written: its line is the OS's)
        assert made[0].accounting()["pending"] == before["pending"] + 1
        acc = resumed()
        assert acc["lost"] == 1 and acc["received"] == before["received"] + 1, acc
        assert sums(acc) == sums(before) and acc["trained"] == before["trained"]
        assert resumed()["lost"] == 1  # killed again before an update: counted once
        with open_session(ZenohOptions()) as session:
            inbox = made[-1]._declare(session)
            try:
                for ep in eps[1:]:
                    made[-1].handle("worker", Keys("resumed").worker_episodes(0), ep.pack())
                assert made[-1].maybe_update()  # its checkpoint now holds the lost one, and
            finally:  # one episode of the three waiting for the next batch (UA 83: it was in
                inbox.close()  # no counter once resumed)
        acc = resumed()
        assert acc["lost"] == 2 and acc["trained"] == before["trained"] + 2, acc
        assert acc["received"] == before["received"] + 4 and sums(acc) == sums(before), acc
        assert resumed() == acc  # and again: counted once
    finally:
        for learner in made:
            learner.journal.close()


def test_a_fresh_learner_starts_its_journal_again_and_a_bad_line_is_skipped(
        tmp_path: Path) -> None:
    """UA 83: a fresh learner (and so `swarm run --train --learner-out DIR`) counted the lines an
    earlier learner that never made a checkpoint left in DIR as its own `lost` (unaccounted
    -2 in a run's result); a line of digits `int` does not take was a traceback."""
    from swarm.learn.config import LearnerConfig
    from swarm.procs.learning.journal import Journal
    from swarm.procs.learning.learner import Learner

    (tmp_path / "l").mkdir()
    journal = tmp_path / "l" / "heard.log"
    journal.write_text("1 0\n2 1\n")
    learner = Learner(SMALL, LearnerConfig(run_id="fresh", policy="vain", out=str(tmp_path / "l")),
                      TrainConfig(batch=2, threads=1))
    learner.open_out()
    try:
        assert learner.accounting()["received"] == 0 and learner.accounting()["lost"] == 0
        assert journal.read_text() == ""
    finally:
        learner.journal.close()
    journal.write_text("\u00b27 1\n5 2\n5 2\nhello\n4 9\n99999999999999999999999 3\n")
    past = Journal(journal).past(4)  # 5 (twice, one episode); the rest skipped or not past
    assert (past.count, past.swarm, past.workers) == (1, set(), {})  # (no s/w marks: nothing)
    journal.write_text("3 s12\n5 w2:40\n6 s9\n7 s\u00b2\n8 w2:41\n9 w2:7\n9 w:3\n9 w2\n")
    past = Journal(journal).past(4)
    assert (past.count, past.swarm, past.workers) == (5, {12, 9}, {2: 41})
    journal.unlink()
    journal.mkdir()  # a folder of its name: one line, not a traceback
    with pytest.raises(ConfigError, match="heard.log cannot be read"):
        Journal(journal).past(0)
    with pytest.raises(ConfigError, match="heard.log cannot be written"):
        Journal(journal).open(fresh=True)




@pytest.mark.procs
def test_a_failed_rollout_bench_keeps_the_log_it_names() -> None:
    """A bench process that fails: the error line says why and names a log that still exists
    (the policy check is bypassed here to make the learner fail for real)."""
    from swarm.bench.rollout import RolloutBenchConfig, bench_rollout

    cfg = RolloutBenchConfig(workers=(1,), seconds=1.0, repeats=1, warmup=0.0)
    object.__setattr__(cfg, "policy", "nearest-frontier")  # what __post_init__ now refuses
    with pytest.raises(RuntimeError) as err:
        bench_rollout(cfg)
    msg = str(err.value)
    assert "needs a learned policy" in msg and "; see " in msg, msg
    log = Path(msg.rsplit("; see ", 1)[1])
    try:
        assert log.is_file() and "needs a learned policy" in log.read_text()
    finally:
        shutil.rmtree(log.parent, ignore_errors=True)


def test_rollout_worker_help_states_the_bounds() -> None:
    r = swarm("rollout-worker", "--help", timeout=60)
    assert r.returncode == 0
    text = " ".join(r.stdout.split())
    assert "[1, 4096]" in text and "[0.1, 3600]" in text and "0: never" in text, text


def test_a_fresh_learner_takes_over_from_the_one_it_replaced(tmp_path: Path) -> None:
    """A learner killed at v23 and replaced by a fresh one (same run, new --out): workers kept
    the v23 weights (they took only higher versions) and the new learner trained on their
    episodes as if they were its own (UA pass). Weights now name the learner process that made
    them: a worker follows another learner's whatever their version, and a learner drops
    episodes played with weights newer than its own, counted as rejected."""
    from swarm.learn.config import LearnerConfig
    from swarm.learn.join import episodes_of
    from swarm.learn.rollout import collect
    from swarm.learn.weights import weights_of
    from swarm.net.learning import Weights
    from swarm.procs.learning.learner import Learner

    old = Learner(SMALL, LearnerConfig(run_id="fresh", policy="vain", out=str(tmp_path / "a")),
                  TrainConfig(batch=2, threads=1))
    new = Learner(SMALL, LearnerConfig(run_id="fresh", policy="vain", out=str(tmp_path / "b")),
                  TrainConfig(batch=2, threads=1))
    assert old.origin != new.origin and min(old.origin, new.origin) > 0
    w = Weights.unpack(new.weights_payload)
    assert (w.version, w.origin) == (0, new.origin)
    assert w.newer_than(23, old.origin) and not w.newer_than(0, new.origin)
    assert Weights.unpack(weights_of(new.policy, 24, new.origin).pack()).newer_than(23, new.origin)
    legacy = msgpack.unpackb(w.pack())[:-1]  # a message of four fields (before the origin)
    assert Weights.unpack(msgpack.packb(legacy)).origin == 0
    roll = collect(new.policy, SMALL, 0, np.arange(3))
    for er in episodes_of(roll, 23):  # played with the replaced learner's v23
        new._accept(er)
    for er in episodes_of(roll, 0):
        new._accept(er)
    assert new.c.rejected == 3 and new.c.episodes == 3 and len(new.ready) == 3


def test_a_robot_follows_a_fresh_learner_too() -> None:
    """A world started by hand with a learner that is replaced: robots that kept the old
    learner's v23 ignored the new one's v0..v23 while it dropped their v23 episodes, so
    neither moved again (review). Robots follow another learner's weights as workers do."""
    from policies.infer.policy import inference_class
    from swarm.learn.weights import weights_of
    from swarm.procs.robot import RobotProcess
    from swarm.procs.runconfig import RunConfig

    pol = inference_class("vain")(SMALL)
    with open_session(ZenohOptions()) as session:
        robot = RobotProcess(0, SMALL, RunConfig(policy="vain", train=True), session, pol)
        for version, origin, then in ((23, 7, (23, 7)), (5, 7, (23, 7)), (0, 9, (0, 9)),
                                      (1, 9, (1, 9))):
            robot.offer_weights(weights_of(pol, version, origin).pack(), "w")
            robot.adopt_weights()
            assert (robot.version, robot.origin) == then
        assert robot.c.weights_bad == 0


def test_training_from_a_config_file_samples_as_the_flag_does(tmp_path: Path) -> None:
    """`[run] train = true` in a --config file trained on greedy actions (robots never
    explored: 327 of 360 decisions were 'stay'); only the --train flag made them sample. An
    explicit greedy = true beside it is one line, exit 2."""
    from swarm.cli import build_parser
    from swarm.cli.common import file_tables
    from swarm.cli.run import run_config

    conf = tmp_path / "t.toml"
    conf.write_text("[run]\ntrain = true\n")
    args = build_parser().parse_args(["run", "--config", str(conf)])
    assert run_config(args, file_tables(args.config)).greedy is False
    args = build_parser().parse_args(["run", "--train"])
    assert run_config(args, {}).greedy is False
    conf.write_text("[run]\ntrain = true\ngreedy = true\n")
    r = swarm("run", "--headless", "--config", str(conf), timeout=60)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "swarm: error: [run] greedy = true with train: a field learner needs sampled actions "
        "(drop greedy)"], r.stderr


@pytest.mark.parametrize("table, says", [
    ("out = 5", "[learner]: out must be str | None, got 5"),  # (a TypeError traceback)
    ('resume = true\nout = "{tmp}/nothere"', "[learner] resume: swarm run starts a fresh "
                                             "learner"),  # (the learner failed after a spawn)
])
def test_a_bad_learner_table_of_swarm_run_is_one_line_before_any_spawn(
        tmp_path: Path, table: str, says: str) -> None:
    conf = tmp_path / "t.toml"
    conf.write_text("[run]\ntrain = true\n[learner]\n" + table.replace("{tmp}", str(tmp_path))
                    + "\n")
    r = swarm("run", "--headless", "--config", str(conf), "--log-dir", str(tmp_path / "logs"),
              timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and says in lines[0], r.stderr[-1500:]
    assert not (tmp_path / "logs").exists() and not (tmp_path / "nothere").exists()


@pytest.mark.parametrize("table, says", [
    ("[run]\ntrain = 1", "[run] train must be true or false, got 1"),  # (was read as true)
    ('[run]\ntrain = true\n[learner]\ngather_only = 0', "[learner] gather_only must be true or "
                                                         "false, got 0"),
    ('[run]\ntrain = true\n[train]\nadv_norm = "yes"', "[train] adv_norm must be true or false"),
])
def test_a_switch_in_a_config_file_must_be_a_boolean(tmp_path: Path, table: str,
                                                    says: str) -> None:
    conf = tmp_path / "t.toml"
    conf.write_text(table + "\n")
    r = swarm("run", "--headless", "--config", str(conf), timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and says in lines[0], r.stderr[-1500:]


def test_a_resumed_learner_may_change_how_it_gathers(trained: Path) -> None:
    """`--resume --max-staleness 5 --join-timeout 1` was taken silently while the help and
    README said only --threads may change: they are how the learner gathers, not the run's
    math; they take effect, and the help says so."""
    from swarm.learn.config import LearnerConfig
    from swarm.procs.learning.learner import Learner

    lc = LearnerConfig(run_id="resumed", policy="vain", out=str(trained / "l"), resume=True,
                       max_staleness=5, join_timeout=1.0)
    kept = Learner(SMALL, lc, TrainConfig(threads=1), {"threads"})
    assert (kept.lc.max_staleness, kept.lc.join_timeout, kept.version) == (5, 1.0, 3)
    r = swarm("learner", "--help", timeout=60)
    assert "--max-staleness and --join-timeout, how this learner gathers, are not held and may " \
        "change" in " ".join(r.stdout.split()), r.stdout


def test_a_learner_keeps_where_each_rollout_worker_is_and_drops_replays(tmp_path: Path) -> None:
    """A rollout worker restarted with its id replayed its seed's episodes from 0 (the learner
    trained on the same maps again). The learner keeps, per worker, one past the last episode
    it heard, serves it in its run record (where a restarted worker starts) and in its
    checkpoint (a resumed learner knows it too); an episode at or before that is a replay, and a
    seed no worker plays is foreign: both dropped as bad, never received."""
    from swarm.learn.config import LearnerConfig
    from swarm.learn.join import episodes_of
    from swarm.learn.rollout import collect
    from swarm.procs.learning.learner import Learner
    from swarm.procs.runconfig import RunRecord

    tc = TrainConfig(batch=8, threads=1, seed=3)
    lc = LearnerConfig(run_id="wk", policy="vain", out=str(tmp_path / "l"))
    learner = Learner(SMALL, lc, tc)
    learner.open_out()
    keys = Keys("wk")

    def play(worker: int, episodes: list[int], seed: int | None = None,
             key: str | None = None) -> None:
        seed = tc.train_seed_offset + tc.seed + worker + 1 if seed is None else seed
        for er in episodes_of(collect(learner.policy, SMALL, seed, np.array(episodes)), 0):
            learner.handle("worker", key or keys.worker_episodes(worker), er.pack())

    try:
        play(0, [0, 1, 2])
        play(5, [7])
        assert RunRecord.unpack(learner.record()).workers == {0: 3, 5: 8}
        play(0, [1, 2, 3])  # a worker restarted from 0 would send 1 and 2 again
        play(0, [0], seed=tc.train_seed_offset + tc.seed)  # (worker -1: nobody's seed)
        play(5, [100], key=keys.worker_episodes(0))  # worker 5's seed on worker 0's key
        assert learner.c.bad == 4 and learner.c.received == 5, learner.c
        assert learner.c.bad_by_key == {keys.worker_episodes(0): 4}
        assert learner.c.worker_episodes == 5
        assert RunRecord.unpack(learner.record()).workers == {0: 4, 5: 8}
        learner.save()
        learner.workers.heard(9, 2**31 - 1)  # (a last episode number: its next stays in range,
        assert RunRecord.unpack(learner.record()).workers[9] == 2**31 - 1  # or no worker joins)
    finally:
        learner.journal.close()
    resumed = Learner(SMALL, LearnerConfig(run_id="wk", policy="vain", out=str(tmp_path / "l"),
                                           resume=True), tc)
    assert resumed.workers.next == {0: 4, 5: 8}
    for bad, why in (([1, 2], "must be a table"), ({-1: 0}, "worker id -1"),
                     ({0: "3"}, "episode '3'"), ({True: 1}, "worker id True"),
                     ({"x": 1}, "worker id 'x'"), ({0: 2**31}, "episode 2147483648")):
        rec = {"world": dataclasses.asdict(SMALL), "workers": bad}
        with pytest.raises(ConfigError, match=f"run record workers: .*{why}"):
            RunRecord.from_record(rec)
    from swarm.procs.learning.rollout_worker import batch_episodes

    assert batch_episodes(0, 4, 2, 3).tolist() == [10, 11, 12]  # a restarted worker's 3rd batch
    assert batch_episodes(0, 2**31 - 3, 0, 3).tolist() == [2**31 - 3, 2**31 - 2, 2**31 - 1]
    with pytest.raises(ConfigError, match=r"rollout worker 7: its next episodes \(2147483646\.\.\) "
                       "pass 2147483647"):  # (a learner that served a next episode near the top)
        batch_episodes(7, 2**31 - 2, 0, 3)
    spec = tmp_path / "spec.json"  # a record as JSON: its worker ids become strings, read back
    RunRecord(SMALL, workers={0: 4, 5: 8}).write(spec)
    assert RunRecord.read(spec).workers == {0: 4, 5: 8}


def _records(e: object, n: int) -> tuple[object, dict[int, object]]:
    """The swarm's records of batched episode `e` (an `EpisodeRollout`): the world's rewards
    and who acted, each robot's trajectory message, whom it heard and what it did, per tick."""
    from swarm.net.learning import EpisodeRecord, RobotRollout, RolloutTick
    from swarm.net.messages import Traj

    robots = {}
    for i in range(n):
        ticks = []
        for t in range(e.actions.shape[0]):
            rec = [int(c) for c in e.recent[t, i] if c >= 0]
            traj = Traj(e.ep, t, i, int(e.pos[t, i, 0]), int(e.pos[t, i, 1]),
                        np.packbits(e.visited[t, i]).tobytes(), rec, e.patch[t, i].tobytes())
            ticks.append(RolloutTick(traj.pack(), np.packbits(e.hears[t, i]).tobytes(),
                                     bool(e.chain_ok[t, i]), int(e.actions[t, i]),
                                     float(e.logp[t, i]), float(e.last_reward[t, i]), 0))
        robots[i] = RobotRollout(e.ep, i, ticks)
    return EpisodeRecord(e.ep, e.reward, e.receivers.copy(), e.metrics), robots


def test_an_episode_the_update_cannot_take_is_refused_not_a_crash(tmp_path: Path) -> None:
    """Review helper 96: a robot record or worker episode in which a robot acted without its
    own message (the features read its row: the learner died of an IndexError at its next
    update), a tick at which no robot acted (a batch of one such episode: a ValueError), a
    worker episode without its log-probabilities (a PPO learner's ValueError) or with rewards of
    3e38 (every loss and the learner's status infinite): each is dropped and counted; and the
    swarm's records join back into the very episode they were made of."""
    from swarm.learn.config import LearnerConfig
    from swarm.learn.join import episodes_of, join
    from swarm.learn.rollout import collect
    from swarm.net.learning import EpisodeRollout
    from swarm.procs.learning.learner import Learner

    lc = LearnerConfig(run_id="refuse", policy="vain", out=str(tmp_path / "l"))
    learner = Learner(SMALL, lc, TrainConfig(batch=1, threads=1))
    eps = episodes_of(collect(learner.policy, SMALL, WORKER0, np.arange(6)), 0)
    world, robots = _records(eps[0], SMALL.n_robots)
    joined = join(SMALL, WORKER0, world, robots)
    for name in ("pos", "visited", "recent", "patch", "present", "hears", "receivers",
                 "chain_ok", "actions", "reward", "last_reward", "logp"):
        assert np.array_equal(getattr(joined, name), getattr(eps[0], name)), name
    deaf = dict(robots)
    t2 = deaf[0].ticks[2]
    own = np.packbits(eps[0].hears[2, 0] & (np.arange(SMALL.n_robots) != 0)).tobytes()
    deaf[0] = type(deaf[0])(deaf[0].ep, 0, [*deaf[0].ticks[:2], t2._replace(heard=own),
                                           *deaf[0].ticks[3:]])
    with pytest.raises(BadMessage, match="robot 0 acted at tick 2 without its own message"):
        join(SMALL, WORKER0, world, deaf)
    world.acted[4] = False  # every robot late at tick 4: joined, batched only if covered
    quiet = join(SMALL, WORKER0, world, robots)
    learner.open_out()
    with open_session(ZenohOptions()) as session:
        learner._declare(session)
        learner.ready, learner.c.episodes = [quiet], 1  # (a batch of 1: nothing covers tick 4)
        assert not learner.maybe_update() and learner.ready == [quiet]  # it waits
        learner.tc = dataclasses.replace(learner.tc, batch=2)
        learner.ready, learner.c.episodes = [quiet, eps[0]], 2
        assert learner.maybe_update() and learner.c.trained == 2 and learner.version == 1
        learner.tc = dataclasses.replace(learner.tc, batch=1)
        learner.ready, learner.c.episodes = [quiet], 1  # ... until it is too stale to train
        learner.version = quiet.version + learner.lc.max_staleness + 1
        assert not learner.maybe_update() and not learner.ready
        assert (learner.c.stale_dropped, learner.c.episodes, learner.c.rejected) == (1, 0, 0)
        learner.version = 1

        def worker(e: EpisodeRollout) -> None:
            learner.handle("worker", Keys("refuse").worker_episodes(0), e.pack())

        e1, e2, e3, e4 = eps[1:5]
        e1.hears[3, 1, 1] = False
        e2.logp = None
        e3.reward[:] = 3e38
        e4.receivers[5] = False  # (a batched episode: every robot acts at every tick)
        for e in (e1, e2, e3, e4):
            worker(e)
        assert learner.c.bad == 4 and learner.c.worker_episodes == 0 and not learner.ready
        worker(eps[5])
        assert learner.c.worker_episodes == 1 and len(learner.ready) == 1
    learner.journal.close()


def test_a_learner_batches_one_seed_at_a_time(tmp_path: Path) -> None:
    """A batch's views share one seed, which hint features draw their noise from: a worker's
    episodes batched behind a swarm episode were trained on the swarm seed's features (review
    helper 96). The learner takes the first seed with a whole batch; `update_due` says so."""
    from swarm.learn.config import LearnerConfig
    from swarm.learn.join import episodes_of
    from swarm.learn.rollout import collect
    from swarm.procs.learning.batches import next_batch, take_batch
    from swarm.procs.learning.learner import Learner

    tc = TrainConfig(batch=2, threads=1)
    learner = Learner(SMALL, LearnerConfig(run_id="seeds", policy="vain",
                                           out=str(tmp_path / "l")), tc)
    swarm_ep = episodes_of(collect(learner.policy, SMALL, tc.seed, np.arange(1)), 0)
    worker = episodes_of(collect(learner.policy, SMALL, WORKER0, np.arange(3)), 0)
    assert next_batch([swarm_ep[0], *worker], 2, by_seed=True) == [1, 2]
    assert next_batch([swarm_ep[0], worker[0]], 2, by_seed=True) is None
    assert next_batch([swarm_ep[0], worker[0]], 2) == [0, 1]  # (no hint: no seed noise)
    # episodes each with a tick nobody decided pair up with those that cover it (review 97)
    a, b, c, d = (dataclasses.replace(worker[k % 3]) for k in range(4))
    for e, t in ((a, 1), (b, 1), (c, 2), (d, 2)):
        e.receivers = e.receivers.copy()
        e.receivers[t] = False
    assert next_batch([a, b, c, d], 2) == [0, 2] and next_batch([a, b], 2) is None
    e = dataclasses.replace(a, receivers=a.receivers.copy())
    e.receivers[2] = False  # (quiet at ticks 1 and 2: review helper 98)
    assert next_batch([e, b, c], 2) == [1, 2]
    # with four batches' worth waiting and no batch to be made of them, the oldest go
    _, left, stale, blocked = take_batch([a] * 8, 2, False, 0, 1)
    assert (len(left), stale, blocked) == (7, 0, 1)
    learner.ready = [swarm_ep[0], worker[0]]
    with open_session(ZenohOptions()) as session:
        learner._declare(session)
        assert learner.status(force=True)["update_due"]
        learner.policy.features.hint = "a hint planner"  # (seed-dependent features)
        assert not learner.status(force=True)["update_due"]


def test_heard_ids_fit_any_team_and_a_lockstep_world_follows_a_fresh_learner() -> None:
    """Whom a robot heard was an int mask: past 64 robots msgpack refused it (the robot died at
    its episode's end) and at 64 the learner's numpy shift overflowed; it is packed bits now.
    A lockstep world kept the replaced learner's version and ignored a fresh learner's lower
    ones, so every episode waited out its start timeout (review helper 96)."""
    from swarm.net.learning import LearnerGate, RobotRollout, RolloutTick, heard_of

    big = dataclasses.replace(SMALL, height=20, width=20, n_robots=130)
    ids = [0, 63, 64, 129]
    mask = np.zeros(130, bool)
    mask[ids] = True
    tick = RolloutTick(b"t", np.packbits(mask).tobytes(), True, 1, -0.5, 0.0, 0)
    back = RobotRollout.unpack(RobotRollout(0, 129, [tick]).pack(), big)
    assert np.flatnonzero(heard_of(back.ticks[0].heard, 130)).tolist() == ids
    with pytest.raises(BadMessage, match="heard"):
        RobotRollout.unpack(RobotRollout(0, 1, [tick._replace(heard=b"\x01")]).pack(), big)
    gate = LearnerGate(0)
    status = {"pending": 0, "update_due": False}
    gate.offer({**status, "version": 7, "last_closed": 20, "origin": 5})
    gate.offer({**status, "version": 3, "last_closed": 21, "origin": 5})  # (older: ignored)
    assert (gate.version, gate.last_closed) == (7, 20)
    gate.offer({**status, "version": 0, "last_closed": 22, "origin": 9})  # a fresh learner
    assert gate.version_for(23) == 0
