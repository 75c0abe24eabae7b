"""The PettingZoo adapter: API conformance, and the very trajectory of the batched core."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pettingzoo")

from pettingzoo.test import parallel_api_test, parallel_seed_test

from world import core
from world.config import ConfigError, WorldConfig
from world.decentral import batch_view, heard_by, robot_view
from world.pettingzoo import encode, obs_size, obs_slices, parallel_env

SMALL = {"height": 8, "width": 9, "n_static": 10, "n_dynamic": 8, "n_robots": 4, "horizon": 12,
         "add_every": 2, "comm_range": 4.0}


@pytest.mark.filterwarnings("ignore:reset options")  # (the api test passes its own options)
def test_parallel_api_conformance() -> None:
    parallel_api_test(parallel_env(**SMALL), num_cycles=40)
    parallel_api_test(parallel_env(), num_cycles=40)  # the paper's world: 10 robots, T = 30


def test_seeded_envs_are_deterministic() -> None:
    parallel_seed_test(lambda: parallel_env(**SMALL), num_cycles=40)


@pytest.mark.parametrize("overrides", [SMALL, {**SMALL, "explore_mode": "sense"},
                                       {**SMALL, "comm_range": math.inf, "spawn": "corner"}])
def test_trajectory_equals_the_batched_core(overrides: dict) -> None:
    env = parallel_env(**overrides)
    cfg = env.cfg
    obs, infos = env.reset(seed=5, options={"episode": 3})
    assert infos["robot_0"] == {"seed": 5, "episode": 3}
    state = core.reset(cfg, 5, [3])
    rng = np.random.default_rng(0)
    for t in range(cfg.horizon):
        expect = encode(cfg, batch_view(cfg, state))[0]
        assert set(obs) == set(env.possible_agents)
        for i, agent in enumerate(env.possible_agents):
            np.testing.assert_array_equal(obs[agent], expect[i])
            assert env.observation_space(agent).contains(obs[agent])
        a = rng.integers(0, 9, size=(1, cfg.n_robots))
        obs, rew, term, trunc, infos = env.step(
            {agent: int(a[0, i]) for i, agent in enumerate(env.agents)})
        r = core.step(cfg, state, a)[0]
        assert [rew[ag] for ag in env.possible_agents] == r.tolist()
        assert not any(term.values())
        assert all(trunc.values()) == (t == cfg.horizon - 1) == (not env.agents)
        assert any(trunc.values()) == all(trunc.values())
    np.testing.assert_array_equal(env.world.pos, state.pos)
    m = core.metrics(cfg, state)
    for i, agent in enumerate(env.possible_agents):
        info = infos[agent]
        assert info["episode_return"] == state.reward_sum[0, i]
        assert info["block_collisions"] == state.block_coll[0, i]
        assert info["robot_collisions"] == state.robot_coll[0, i]
        assert info["elratio"] == m.elratio[0] and info["success"] == m.success[0]
        assert info["team_reward_mean"] == m.reward[0]
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})


def test_reset_keys_episodes_by_seed_and_counter() -> None:
    env = parallel_env(**SMALL)
    cfg = env.cfg
    lay = core.Layout.of(cfg)
    sl = obs_slices(cfg)["position"]

    def starts(obs: dict) -> list[list[int]]:
        yx = np.stack([obs[a][sl] for a in env.possible_agents]) * [cfg.height - 1, cfg.width - 1]
        return np.rint(yx).astype(int).tolist()

    first, _ = env.reset(seed=9)
    second, info = env.reset()
    assert info["robot_0"]["episode"] == 1
    assert starts(first) == lay.to_yx(core.reset(cfg, 9, [0]).pos[0]).tolist()
    assert starts(second) == lay.to_yx(core.reset(cfg, 9, [1]).pos[0]).tolist()
    again, _ = env.reset(seed=9)
    assert starts(again) == starts(first)
    other, _ = env.reset(seed=10)
    assert starts(other) != starts(first)
    numpy_seed, _ = env.reset(seed=np.int64(9))  # numpy's ints are seeds too
    assert starts(numpy_seed) == starts(first)
    for bad in ({"seed": 1.5}, {"seed": -1}, {"options": {"episode": 2**70}},
                {"options": {"episode": "3"}}):  # never truncated, wrapped or overflowed
        with pytest.raises(ValueError, match="seed|episode"):
            env.reset(**bad)


def test_observation_features_mean_what_the_docs_say() -> None:
    env = parallel_env(**{**SMALL, "comm_range": math.inf})
    cfg = env.cfg
    sl = obs_slices(cfg)
    assert sl["heard_positions"].stop == obs_size(cfg) == env.observation_space("robot_0").shape[0]
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    for _ in range(4):
        obs, *_ = env.step({a: int(rng.integers(9)) for a in env.agents})
    state = env.world
    lay = core.Layout.of(cfg)
    pos = lay.to_yx(state.pos[0])
    patches = core.patches(cfg, state)[0]
    union = state.visited[0].any(0)
    v = cfg.vision
    for i, agent in enumerate(env.possible_agents):
        o = obs[agent]
        yx = o[sl["position"]] * [cfg.height - 1, cfg.width - 1]
        assert np.rint(yx).astype(int).tolist() == pos[i].tolist()
        assert o[sl["tick"]][0] == pytest.approx(4 / cfg.horizon)
        planes = o[sl["patch"]].reshape(3, v, v)
        np.testing.assert_array_equal(planes[0], (patches[i] & 3) == 1)
        np.testing.assert_array_equal(planes[1], (patches[i] & 3) == 2)
        np.testing.assert_array_equal(planes[2], (patches[i] & 4) != 0)
        assert planes[2][v // 2, v // 2] == 1  # the robot sees itself
        np.testing.assert_array_equal(o[sl["team_visited"]], union)  # everyone in range
        others = {tuple(p) for j, p in enumerate(pos.tolist()) if j != i}
        cells = {divmod(int(c), cfg.width) for c in np.flatnonzero(o[sl["heard_positions"]])}
        assert cells == others


def test_out_of_range_robots_are_not_in_the_observation() -> None:
    env = parallel_env(**{**SMALL, "comm_range": 0.0, "n_robots": 3})
    obs, _ = env.reset(seed=2)
    cfg = env.cfg
    sl = obs_slices(cfg)
    for i, agent in enumerate(env.possible_agents):
        np.testing.assert_array_equal(obs[agent][sl["team_visited"]], env.world.visited[0, i])
        assert not obs[agent][sl["heard_positions"]].any()  # distinct starts: nobody at range 0


def test_one_robots_own_view_encodes_like_the_batch() -> None:
    """A robot process that encodes only what it heard gets the adapter's observation."""
    cfg = WorldConfig(**SMALL)
    state = core.reset(cfg, 4, [0, 1])
    rng = np.random.default_rng(4)
    for _ in range(3):
        core.step(cfg, state, rng.integers(0, 9, size=(2, cfg.n_robots)))
    view = batch_view(cfg, state)
    full = encode(cfg, view)
    for g in range(2):
        for i in range(cfg.n_robots):
            own = robot_view(cfg, state.seed, int(state.episodes[g]), view.tick, i,
                             heard_by(cfg, view, g, i), float(state.last_reward[g, i]))
            np.testing.assert_array_equal(encode(cfg, own)[0, i], full[g, i])


def test_missing_agents_stay_and_bad_actions_are_rejected() -> None:
    env = parallel_env(**SMALL)
    env.reset(seed=3)
    before = env.world.pos.copy()
    env.step({"robot_0": 0})
    np.testing.assert_array_equal(env.world.pos, before)
    assert env.world.block_coll.sum() == 0
    with pytest.raises(ValueError, match="action must be"):
        env.step({"robot_0": 9})
    with pytest.raises(ValueError, match="unknown agent"):
        env.step({"robot_99": 0})


def test_config_overrides_are_checked() -> None:
    with pytest.raises(ConfigError, match="unknown key"):
        parallel_env(n_robot=3)
    env = parallel_env(WorldConfig(n_robots=3), horizon=7)
    assert env.cfg.n_robots == 3 and env.cfg.horizon == 7
    assert env.possible_agents == ["robot_0", "robot_1", "robot_2"]
    assert env.action_space("robot_2").n == 9


def test_ansi_render_shows_robots_and_blocks() -> None:
    env = parallel_env(render_mode="ansi", **SMALL)
    env.reset(seed=0)
    text = env.render()
    rows = text.splitlines()
    assert len(rows) == SMALL["height"] and all(len(r) == SMALL["width"] for r in rows)
    assert sum(ch == "#" for ch in text) == SMALL["n_static"]
    assert {str(i) for i in range(SMALL["n_robots"])} <= set(text)


def module_level_imports(tree: ast.AST) -> list[str]:
    """Modules imported when a file is imported (imports inside functions are lazy: skipped)."""
    out: list[str] = []
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            continue
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out.append(node.module or "")
        out += module_level_imports(node)
    return out


def test_only_the_adapter_imports_pettingzoo() -> None:
    """pettingzoo and gymnasium stay optional: no other module imports them (or the adapter)."""
    root = Path(__file__).resolve().parents[1]
    offenders = []
    for pkg in ("world", "policies", "swarm", "deploy"):
        for path in (root / pkg).rglob("*.py"):
            if path == root / "world" / "pettingzoo.py":
                continue
            for name in module_level_imports(ast.parse(path.read_text())):
                parts = name.split(".")
                if "pettingzoo" in parts or parts[0] == "gymnasium":
                    offenders.append(f"{path.relative_to(root)}: {name}")
    assert offenders == []


def test_hostile_values_through_the_adapter_are_one_line_errors() -> None:
    """UA pass: a list of actions, a bool action, a dict for the config and options that are no
    dict gave AttributeErrors or were taken; a typo in options was silently ignored."""
    env = parallel_env(**SMALL)
    env.reset(seed=0)
    for bad in ([1, 2, 3, 4], None, np.zeros(4, dtype=np.int64)):
        with pytest.raises(ValueError, match="actions must be a dict"):
            env.step(bad)  # type: ignore[arg-type]
    for action in (True, np.bool_(True), 1.5, 9):
        with pytest.raises(ValueError, match="action must be an int in 0..8"):
            env.step({"robot_0": action})
    with pytest.raises(ValueError, match="options must be None or a dict"):
        env.reset(options=[("episode", 1)])  # type: ignore[arg-type]
    with pytest.warns(UserWarning, match="'epsiode'"):
        env.reset(seed=0, options={"epsiode": 3})
    with pytest.raises(ValueError, match="config must be a WorldConfig"):
        parallel_env({"n_robots": 3})  # type: ignore[arg-type]
    _, rewards, *_ = env.step({})  # standing still on a fresh start cell: 0 (never -0.0)
    assert all(math.copysign(1.0, r) > 0 for r in rewards.values() if r == 0)


def test_the_module_docstring_s_recipe_gives_swarm_eval_s_figures() -> None:
    """The README points at world/pettingzoo.py's docstring for running a policy of this
    project inside the adapter with `swarm eval`'s figures; the recipe was not there."""
    import world.pettingzoo as pz
    from swarm.common.policy_spec import build_policy
    from swarm.learn.evaluate import evaluate

    doc = pz.__doc__ or ""
    start = doc.index("    from swarm.common.policy_spec import build_policy")
    recipe = "\n".join(line[4:] for line in doc[start:].splitlines())
    scope: dict = {"parallel_env": parallel_env}
    exec(recipe, scope)  # noqa: S102 (the docstring's own text)
    cfg = scope["env"].cfg
    ev = evaluate(cfg, build_policy("nearest-frontier", cfg), 0, 3)
    assert scope["elratio"] == pytest.approx(ev.elratio.tolist())
