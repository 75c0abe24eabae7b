"""Reference planners (issue 17): the full-knowledge oracle and the perfect-radio central one."""

from __future__ import annotations

import importlib
import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from policies import BASELINES, REGISTRY, make_policy, policy_class
from policies.base import Policy
from policies.central import CentralPolicy
from policies.oracle import OracleConfig, OraclePolicy, certify, plan_episode, replay
from swarm.learn.evaluate import evaluate
from world import core
from world.config import WorldConfig
from world.decentral import batch_view

CFG = WorldConfig()
FAST = OracleConfig(iters=8, beam=32)
ROOT = Path(__file__).resolve().parents[1]
SMALL = WorldConfig(height=8, width=8, n_static=10, n_dynamic=8, n_robots=2, horizon=10)


def _evaluate():
    """The batched evaluator, wherever the swarm package keeps it."""
    for mod in ("swarm.learn.evaluate", "swarm.evaluate"):
        if importlib.util.find_spec(mod) is not None:
            return importlib.import_module(mod).evaluate
    pytest.skip("batched evaluator not found")


def test_registered_and_not_decentralized() -> None:
    assert Policy.decentralized is True
    assert policy_class("nearest-frontier").decentralized is True
    for name, cls in (("oracle", OraclePolicy), ("central", CentralPolicy)):
        assert name in REGISTRY and name not in BASELINES
        assert policy_class(name) is cls
        assert cls.decentralized is False and cls.learned is False


def test_oracle_replay_matches_evaluator_and_beats_frontier() -> None:
    evaluate = _evaluate()
    oracle = OraclePolicy(CFG, search=FAST)
    res = evaluate(CFG, oracle, 0, 3, batch=3)
    frontier = evaluate(CFG, make_policy("coordinated-frontier", CFG), 0, 3, batch=3)
    for k, ep in enumerate(range(3)):
        plan = plan_episode(CFG, 0, ep, FAST)
        assert plan.elratio == pytest.approx(res.elratio[k])
        assert plan.planned_elratio == pytest.approx(plan.elratio)
        assert plan.block_collisions == 0 and res.block_collisions[k] == 0
        state = replay(CFG, 0, ep, plan.actions)
        assert core.metrics(CFG, state).elratio[0] == pytest.approx(res.elratio[k])
    assert (res.elratio >= frontier.elratio).all()
    assert res.success.all()


def test_oracle_plan_does_not_depend_on_numpys_simd_kernels() -> None:
    """The same plan with numpy's AVX2/AVX-512 kernels switched off: the committed oracle figures
    once came from np.argpartition, whose choice among equal ranks differs by kernel."""
    code = ("import sys; from world.config import WorldConfig; "
            "from policies.oracle import OracleConfig, plan_episode; "
            "sys.stdout.write(plan_episode(WorldConfig(), 0, 0, OracleConfig(iters=8, beam=32))"
            ".paths.tobytes().hex())")
    env = dict(os.environ, NPY_DISABLE_CPU_FEATURES=NO_SIMD)
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    assert out == plan_episode(CFG, 0, 0, FAST).paths.tobytes().hex()


NO_SIMD = "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"


@pytest.mark.parametrize("name,episodes", [("central", 4), ("chain-plan", 1)])
def test_planners_act_alike_without_numpys_simd_kernels(name: str, episodes: int) -> None:
    """`central` (and `team-beam`, which runs its search) kept its beam with np.argpartition:
    with AVX2 on, 20 held-out episodes gave 0.93625, without it 0.9325. Per-episode elratios
    with numpy's vector kernels switched off equal this process's."""
    code = ("import sys; from world.config import WorldConfig; from policies import make_policy; "
            "from swarm.learn.evaluate import evaluate; c = WorldConfig(); "
            f"r = evaluate(c, make_policy({name!r}, c), seed=0, n_episodes={episodes}); "
            "sys.stdout.write(r.elratio.tobytes().hex())")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         check=True, env=dict(os.environ, NPY_DISABLE_CPU_FEATURES=NO_SIMD)).stdout
    here = evaluate(CFG, make_policy(name, CFG), seed=0, n_episodes=episodes)
    assert out == here.elratio.tobytes().hex()


@pytest.mark.parametrize("episode", [7, 14])
def test_committed_oracle_figures_reproduce(episode: int) -> None:
    """results/reference/oracle_60.json is what today's oracle plans (two of its fastest
    episodes): the README quotes it as what `swarm eval --policy oracle` gives."""
    saved = json.loads((ROOT / "results/reference/oracle_60.json").read_text())
    row = saved["per_episode"][episode]
    plan = plan_episode(CFG, saved["seed"], episode, OracleConfig(**{
        k: math.inf if v is None else tuple(v) if isinstance(v, list) else v
        for k, v in saved["search"].items()}))
    assert (plan.elratio, plan.robot_collisions, plan.rounds, plan.covered) == \
        (row["elratio"], row["robot_collisions"], row["rounds"], row["covered"])


def test_certificate_bounds_the_plan() -> None:
    pytest.importorskip("scipy")
    for ep in range(3):
        plan = plan_episode(SMALL, 1, ep, OracleConfig(iters=20, beam=32))
        cert = certify(SMALL, 1, ep, plan, time_limit=20.0, force_milp=True)
        assert cert.method.startswith("milp")
        assert cert.bound >= cert.plan_value == plan.covered
        if cert.proven:
            assert cert.bound == cert.plan_value
    # robots that never move: far from optimal, and the IP says so
    start = np.repeat(plan.paths[:, :1], SMALL.horizon + 1, axis=1)
    lazy = certify(SMALL, 1, 2, start, time_limit=20.0, force_milp=True)
    assert lazy.plan_value == 0 and not lazy.proven and lazy.bound >= plan.covered


def _run(cfg: WorldConfig, state: core.WorldState, policy: Policy, ticks: int) -> list[np.ndarray]:
    policy.reset(state.batch)
    acts = []
    for _ in range(ticks):
        a = policy.act(batch_view(cfg, state))
        acts.append(a.copy())
        core.step(cfg, state, a)
    return acts


def test_central_ignores_the_future_schedule() -> None:
    blocks, starts, dyn = core.generate_episode(CFG, 0, 5)
    due = core.dynamic_due(CFG)
    cut = 12
    rng = np.random.default_rng(0)
    taken = {tuple(c) for c in starts} | {tuple(c) for c in dyn}
    spare = [c for c in zip(*np.nonzero(~blocks), strict=True) if c not in taken]
    moved = dyn.copy()
    late = np.flatnonzero(due > cut)
    moved[late] = np.array(spare)[rng.choice(len(spare), size=len(late), replace=False)]
    assert not np.array_equal(moved, dyn)
    runs = []
    for d in (dyn, moved):
        state = core.from_layout(CFG, blocks[None], starts[None], d[None], seed=0,
                                 episodes=np.array([5]))
        runs.append(_run(CFG, state, CentralPolicy(CFG), cut + 1))
    for t in range(cut + 1):  # ticks 0..cut saw the same world
        np.testing.assert_array_equal(runs[0][t], runs[1][t])


def test_central_beats_nearest_frontier() -> None:
    evaluate = _evaluate()
    central = evaluate(CFG, CentralPolicy(CFG), 0, 20, batch=20)
    nearest = evaluate(CFG, make_policy("nearest-frontier", CFG), 0, 20, batch=20)
    assert central.elratio.mean() >= nearest.elratio.mean()
    assert central.block_collisions.sum() == 0


def test_team_beam_is_central_when_everyone_hears_everyone_and_differs_when_not() -> None:
    """`team-beam` is `central`'s planner over one robot's belief and heard team: with a radio
    that reaches the whole map every robot knows what `central` knows and, its beam noise keyed
    by the planned robot, makes `central`'s joint plan; with a short radio the plans part."""
    assert policy_class("team-beam").decentralized is True
    differ = 0
    for comm_range, same in ((100.0, True), (2.0, False)):
        cfg = WorldConfig(height=12, width=12, n_static=20, n_dynamic=10, n_robots=5,
                          comm_range=comm_range, horizon=12, add_every=2)
        state = core.reset(cfg, seed=1, episodes=list(range(6)))
        beam, central = make_policy("team-beam", cfg), CentralPolicy(cfg)
        beam.reset(6)
        central.reset(6)
        while not state.done:
            view = batch_view(cfg, state)
            mine, theirs = beam.act(view), central.act(view)
            if same:
                np.testing.assert_array_equal(mine, theirs, err_msg=f"tick {state.t}")
            else:
                differ += int((mine != theirs).sum())
            core.step(cfg, state, theirs)
    assert differ > 0


def test_beam_duplicates_keep_the_first_of_equal_keys() -> None:
    """`duplicates` (the beam's state dedup by one value sort) marks exactly what a stable
    argsort marks: every key equal to one earlier in its row."""
    from policies.central import duplicates

    rng = np.random.default_rng(0)
    for c in (1, 9, 72, 216, 300):
        keys = rng.integers(0, 2**63, size=(50, c), dtype=np.int64).astype(np.uint64)
        if c > 4:  # copies, some before and some after their first
            keys[:, 3] = keys[:, c - 1]
            keys[::2, 0] = keys[::2, 2]
        order = np.argsort(keys, axis=1, kind="stable")
        sk = np.take_along_axis(keys, order, 1)
        want = np.zeros(keys.shape, dtype=bool)
        np.put_along_axis(want, order[:, 1:], sk[:, 1:] == sk[:, :-1], 1)
        np.testing.assert_array_equal(duplicates(keys), want)
        assert want.any() == (c > 4)


def _chain_world() -> WorldConfig:
    return WorldConfig(height=12, width=12, n_static=20, n_dynamic=10, n_robots=5,
                       comm_range=4.0, horizon=12, add_every=2)


@pytest.mark.parametrize("lost", [False, True])
def test_chain_plan_robot_by_robot_equals_the_batch(lost: bool) -> None:
    """`chain-plan` in robot processes: each robot, with its own belief and memory, decides from
    its predecessor's message (the plan as it left it) what the batched chain decides, and sends
    the same plan; with a lost message (`chain_ok`) it heads a chain, in both settings."""
    from policies.chain_plan import ChainPlan
    from world.decentral import heard_by, robot_view

    cfg = _chain_world()
    state = core.reset(cfg, seed=3, episodes=[0, 1])
    batched = ChainPlan(cfg)
    batched.reset(2)
    robots = {(g, i): ChainPlan(cfg) for g in range(2) for i in range(cfg.n_robots)}
    for pol in robots.values():
        pol.reset(1)
    heads = 0
    while not state.done:
        view = batch_view(cfg, state)
        if lost:  # every robot 2 misses its predecessor's message
            view.chain_ok = np.ones(view.receivers.shape, dtype=bool)
            view.chain_ok[:, 2] = False
        d = batched.decide(view)
        for (g, i), pol in robots.items():
            own = robot_view(cfg, state.seed, int(state.episodes[g]), state.t, i,
                             heard_by(cfg, view, g, i), float(view.last_reward[g, i]))
            own.chain_ok = None if view.chain_ok is None else view.chain_ok[g][None]
            prep = pol.prepare_chain(own)
            p = int(prep.pred[0])
            if p < 0 or (lost and i == 2):
                heads += 1
            msg = None if p < 0 else d.state[g, p][None]
            if msg is not None:
                assert pol.state_ok(msg[0], state.t)
            acts, sent = pol.act_with_chain(own, msg, None if p < 0 else d.actions[g, p:p + 1],
                                            prepared=prep)
            assert acts[0, i] == d.actions[g, i], f"robot {i} of group {g} at tick {state.t}"
            assert np.array_equal(sent[0], d.state[g, i])
        core.step(cfg, state, d.actions)
    assert heads > 2 * cfg.horizon  # robot 0 always heads; others do when they hear no lower id


def test_chain_plan_memory_stays_one_plan_per_robot_without_reset() -> None:
    """As a network's hint nobody resets the planner between episodes: its memory of sent plans
    keeps one entry per (group, robot), not one per episode."""
    from policies.chain_plan import ChainConfig, ChainPlan

    cfg = _chain_world()
    pol = ChainPlan(cfg, ChainConfig(head_iters=0, head_beam=4, beam=4))
    pol.reset(1)
    for episode in range(3):
        state = core.reset(cfg, seed=1, episodes=[episode])
        for _ in range(3):
            view = batch_view(cfg, state)
            core.step(cfg, state, pol.moves(view, pol.belief.snapshot(view))[None])
    assert len(pol.memory) == cfg.n_robots
    assert {ep for ep, _, _ in pol.memory.values()} == {2}


def test_chain_plan_refuses_a_plan_that_fails_its_checks() -> None:
    """Every field of the plan message has a range; a message outside it is not a plan (the
    robot process counts it as a lost hidden-state message and heads a chain)."""
    from policies.chain_plan import ChainPlan

    cfg = _chain_world()
    pol = ChainPlan(cfg)
    t, left = 4, cfg.horizon - 4 + 1
    good = pol.encode({0: np.array([13] * left), 3: np.arange(left) + 26})
    assert pol.state_ok(good, t) and set(pol.decode(good, t)) == {0, 3}
    assert np.array_equal(pol.decode(good, t)[3], np.arange(left) + 26)
    rows = good.reshape(cfg.n_robots, -1)

    def bad(edit) -> np.ndarray:
        r = rows.copy()
        edit(r)
        return r.ravel()

    def put(row: int, col: int, value: float) -> np.ndarray:
        return bad(lambda r: r.__setitem__((row, col), value))

    assert rows.shape == (cfg.n_robots, 4)  # id, first cell, 12 moves packed 6 to a float
    beyond = rows[0, 3] + 81  # robot 0's 9th move digit: past the 8 moves left at tick 4
    for msg in (good[:-1], np.full_like(good, np.nan), put(1, 0, 5), put(1, 0, 0),
                put(0, 0, 0.5), put(0, 1, 144), put(1, 1, -1), put(0, 2, 0.5), put(0, 2, -1),
                put(0, 2, 9 ** 6), put(0, 3, beyond), put(1, 1, 28), put(2, 3, 7)):
        assert not pol.state_ok(msg, t)
    everyone = WorldConfig(**{**cfg.__dict__, "comm_range": float("inf")})
    view = batch_view(everyone, core.reset(everyone, seed=0, episodes=[0]))
    view.receivers = np.arange(cfg.n_robots)[None] == 1  # robot 1 alone: its predecessor is 0
    with pytest.raises(ValueError, match="state_ok"):
        ChainPlan(everyone).act_with_chain(view, np.full((1, pol.state_size), np.nan, np.float32),
                                           np.array([0]))


def test_chain_plan_message_fits_the_wire_schema() -> None:
    """The largest plan message (every robot, every packed move digit 8) passes the
    hidden-state message's checks on the wire (magnitude bound, size)."""
    from policies.chain_plan import BASE, MOVES_PER_FLOAT, ChainPlan
    from swarm.net.messages import Hidden

    cfg = WorldConfig(n_robots=200, height=40, width=40)
    pol = ChainPlan(cfg)
    worst = np.full(pol.state_size, BASE ** MOVES_PER_FLOAT - 1, dtype="<f4")
    worst[::2 + pol.words] = cfg.n_robots - 1
    msg = Hidden.unpack(Hidden(0, 1, 0, 0, worst.tobytes()).pack(), cfg, pol.state_size)
    assert np.array_equal(msg.vector(), worst)


def test_chain_plan_config_and_message_size_are_checked() -> None:
    from policies.chain_plan import ChainConfig, ChainPlan
    from world.config import ConfigError

    for bad in ({"head_iters": -1}, {"head_beam": 0}, {"beam": 1.5}, {"iters": True}):
        with pytest.raises(ConfigError, match="chain-plan"):
            ChainConfig(**bad)  # type: ignore[arg-type]
    assert ChainPlan(WorldConfig(n_robots=200, height=40, width=40)).state_size == 1400
    with pytest.raises(ConfigError, match="at most 4096"):
        ChainPlan(WorldConfig(n_robots=200, height=40, width=40, horizon=200))
