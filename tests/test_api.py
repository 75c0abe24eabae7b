"""The project used as a Python library: wrong arguments to the world's and the policies' public
functions are one-line errors naming the bad item, not silent wrong figures or numpy
tracebacks (user-acceptance findings)."""

from __future__ import annotations

import numpy as np
import pytest

from world import core
from world.config import ConfigError, WorldConfig
from world.decentral import batch_view, traj_messages

CFG = WorldConfig(n_robots=3)


@pytest.mark.parametrize("other, named", [
    (WorldConfig(n_robots=3, height=25, width=25), "height 25 (state's: 20), width 25"),
    (WorldConfig(n_robots=3, vision=7), "vision 7 (state's: 5)"),
    (WorldConfig(n_robots=3, horizon=10), "horizon 10 (state's: 30)")])
def test_a_state_refuses_a_config_it_was_not_reset_with(other: WorldConfig, named: str) -> None:
    """A 25 x 25 config on a 20 x 20 state divided elratio by 625 cells and decoded positions
    on the wrong row width without a word; every (cfg, state) function now refuses it."""
    state = core.reset(CFG, 0, [0])
    calls = [lambda: core.step(other, state, np.full((1, 3), 3)),
             lambda: core.metrics(other, state), lambda: batch_view(other, state),
             lambda: core.patches(other, state),
             lambda: core.elratio(other, state), lambda: traj_messages(other, state)]
    for call in calls:
        with pytest.raises(ConfigError, match="differs from the one the state was reset with") as e:
            call()
        assert named in str(e.value) and "\n" not in str(e.value)
    assert state.t == 0
    same = WorldConfig(n_robots=3)  # an equal config (not the same object) is the same world
    core.step(same, state, np.full((1, 3), 3))
    assert core.metrics(same, state).elratio.shape == (1,) and batch_view(same, state).tick == 1


SMALL = WorldConfig(height=5, width=5, n_static=0, n_dynamic=2, n_robots=2, horizon=9)


@pytest.mark.parametrize("starts, dynamic, message", [
    ([[[0, 0], [1, 1]]], [[[9, 9], [1, 2]]], r"dynamic\[0\]\[0\] = \[9, 9\] lies off the 5 x 5"),
    ([[[0, 0], [1, 5]]], [[[2, 2], [1, 2]]], r"starts\[0\]\[1\] = \[1, 5\] lies off the 5 x 5"),
    ([[[0.5, 0], [1, 1]]], [[[2, 2], [1, 2]]], "starts must be integer"),
    ([[[1, 1], [1, 1]]], [[[2, 2], [1, 2]]],
     r"starts\[0\]\[0\] and starts\[0\]\[1\] are both \[1, 1\]"),
    ([[[0, 0], [1, 1], [2, 2]]], [[[2, 2], [1, 2]]], r"starts must be \[B, 2, 2\] = \[1, 2, 2\]"),
    ([[[0, 0], [3, 3]]], [[[2, 2]]], r"dynamic must be \[B, 2, 2\]"),
    ([[[0, 0], [3, 3]]], [[[2, 2], [1, 2]]], r"starts\[0\]\[1\] = \[3, 3\] is a block")])
def test_a_hand_built_map_is_checked_up_front(starts: list, dynamic: list, message: str) -> None:
    """An off-grid dynamic block was accepted and raised IndexError deep in numpy at its step,
    float starts and two robots on one cell were accepted, a wrong robot count was numpy's
    reshape error: each is now one line naming the bad entry."""
    blocks = np.zeros((1, 5, 5), dtype=bool)
    blocks[0, 3, 3] = True
    with pytest.raises(ValueError, match=message) as e:
        core.from_layout(SMALL, blocks, starts, dynamic)
    assert "\n" not in str(e.value)
    state = core.from_layout(SMALL, blocks, [[[0, 0], [1, 1]]], [[[4, 4], [1, 2]]])
    while not state.done:
        core.step(SMALL, state, np.zeros((1, 2), dtype=np.int64))
    assert state.dyn_active.all()


def test_a_seed_that_is_no_integer_is_called_so() -> None:
    """`core.reset(cfg, 1.5, [0])` said "seed must lie in [0, 2147483647], got 1.5", as if 1.5
    were out of range; a bool, a float or a string is now named as no integer."""
    from world.pettingzoo import SwarmParallelEnv

    env = SwarmParallelEnv(SMALL)
    for call, name, bad in ((lambda: core.reset(SMALL, 1.5, [0]), "seed", "1.5"),
                            (lambda: core.reset(SMALL, True, [0]), "seed", "True"),
                            (lambda: env.reset(seed=1.0), "seed", "1.0"),
                            (lambda: env.reset(seed=0, options={"episode": "3"}), "episode",
                             "'3'")):
        with pytest.raises(ConfigError, match=f"^{name} must be an integer in "
                                              fr"\[0, 2147483647\], got {bad}$"):
            call()
    with pytest.raises(ConfigError, match=r"^seed must lie in \[0, 2147483647\], got -1$"):
        core.reset(SMALL, -1, [0])


def test_one_class_is_called_decision_and_the_networks_record_is_not_it() -> None:
    """`policies.base.Decision` (actions, state) is the chained-policy interface; the shipped
    CommAttn's `decide` returned another class of that name, and `actions, state = d` failed
    on it. The network's record is `NetDecision`, read by name."""
    import importlib
    import pkgutil

    import policies
    from policies.base import Decision
    from policies.infer.policy import NetDecision
    from policies.learned import LearnedPolicy

    called = {obj for info in pkgutil.walk_packages(policies.__path__, "policies.")
              for obj in vars(importlib.import_module(info.name)).values()
              if isinstance(obj, type) and obj.__name__ == "Decision"}
    assert called == {Decision}
    cfg = WorldConfig(height=8, width=8, n_static=6, n_dynamic=4, n_robots=3, horizon=6)
    policy = policies.make_policy("commattn", cfg)
    assert isinstance(policy, LearnedPolicy)
    d = policy.decide(batch_view(cfg, core.reset(cfg, 0, [0])))
    assert isinstance(d, NetDecision) and d.actions.shape == (1, 3)
    assert d.state is not None and d.state.shape[:2] == (1, 3)


def test_python_callers_are_told_the_argument_not_only_the_flag(tmp_path) -> None:
    """`build_policy(..., checkpoint=...)` on a planner said "--checkpoint applies ...", and
    `trainer.main` into a used folder "pass --resume or choose another --out": flags a Python
    caller never typed. Each now names the argument too."""
    from swarm.common.policy_spec import build_policy
    from swarm.learn.config import TrainConfig
    from swarm.learn.trainer import main

    with pytest.raises(ConfigError, match=r"^a checkpoint \(--checkpoint\) applies to learned "
                                          "policies only, not 'nearest-frontier'$"):
        build_policy("nearest-frontier", SMALL, checkpoint=str(tmp_path / "x.pt"))
    (tmp_path / "checkpoint.pt").write_bytes(b"")
    with pytest.raises(ConfigError, match=r"resume it \(--resume, resume=True\) or choose "
                                          r"another output folder \(--out\)$"):
        main(TrainConfig(policy="commattn", epochs=1), SMALL, tmp_path)


def test_an_eval_result_labels_its_rows_with_its_own_policy() -> None:
    """`EvalResult.rows()` asked for the policy name the result already holds."""
    from policies import make_policy
    from swarm.learn.evaluate import evaluate

    res = evaluate(SMALL, make_policy("random", SMALL), seed=0, n_episodes=2)
    assert [(r["policy"], r["episode"]) for r in res.rows()] == [("random", 0), ("random", 1)]
    assert {r["policy"] for r in res.rows("mine")} == {"mine"}


def test_the_public_helpers_say_what_they_are() -> None:
    """UA pass: these had no docstring (a `help()` user saw only a signature)."""
    from world.decentral import View
    from world.pettingzoo import SwarmParallelEnv, obs_size

    for obj in (core.metrics, View.predecessor, obs_size, SwarmParallelEnv.observation_space,
                SwarmParallelEnv.action_space, SwarmParallelEnv.close, WorldConfig.cells):
        assert (obj.__doc__ or "").strip(), obj
    assert "finished episode" in core.metrics.__doc__ and "False" in core.metrics.__doc__


def test_torch_logits_rows_are_robot_major_and_it_remembers() -> None:
    """What `LearnedPolicy.torch_logits`' docstring says: its rows follow the features (robot
    0 of every group first), not `receiver_index`'s group-major order, and it folds the view
    into the policy's memory as a decision does."""
    from policies import make_policy
    from policies.base import receiver_index

    cfg = WorldConfig(height=8, width=8, n_static=6, n_dynamic=4, n_robots=3, horizon=6)
    twin, torch_side = make_policy("commattn", cfg), make_policy("commattn", cfg)
    torch_side.net.load_state_dict(twin.net.state_dict())
    for policy in (twin, torch_side):
        policy.reset(2)
    view = batch_view(cfg, core.reset(cfg, 0, [0, 1]))
    _, value = torch_side.torch_logits(view)
    assert torch_side.team.visited.any()  # (the decision's remember(), done by torch_logits)
    decided = twin.decide(view).value
    tok = twin.features(view)
    assert tok.robot.tolist() == [0, 0, 1, 1, 2, 2]
    np.testing.assert_allclose(value.numpy(), decided[tok.group, tok.robot], atol=1e-5)
    g, i = receiver_index(view)
    assert not np.allclose(value.numpy(), decided[g, i], atol=1e-5)
