"""`swarm train --imitate TEACHER`: DAgger toward a non-learned planner (the learner's sampled
actions drive the episodes; the teacher's action at each visited view is the target)."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import numpy as np
import pytest
import torch
from rich.console import Console

from policies import make_policy
from policies.checkpoint import load_checkpoint
from swarm.learn.config import TrainConfig
from swarm.learn.rollout import collect
from swarm.learn.trainer import main
from swarm.learn.update import update
from world import core
from world.config import ConfigError, WorldConfig
from world.decentral import batch_view

SMALL = WorldConfig(height=8, width=8, n_static=6, n_dynamic=4, n_robots=4, horizon=8, add_every=2,
                    vision=3, comm_range=3.0, recent_len=4)


def fresh(name: str = "commattn", seed: int = 0):
    torch.manual_seed(seed)
    return make_policy(name, SMALL)


@pytest.mark.parametrize("name", ["central", "team-beam"])
def test_labels_are_the_teachers_actions_on_the_views_the_learner_visited(name: str) -> None:
    roll = collect(fresh(), SMALL, 5, np.arange(6), teacher=name)
    assert roll.labels is not None and len(roll.labels) == len(roll.views) == SMALL.horizon
    teacher = make_policy(name, SMALL)
    teacher.reset(6)
    for view, label in zip(roll.views, roll.labels, strict=True):  # one draw: a one-bit set
        one = np.where(view.receivers, 1 << teacher.act(view), 0)
        np.testing.assert_array_equal(one, label)
    # the learner, not the teacher, drove the episodes: the actions taken differ from the labels
    rec = np.stack([v.receivers for v in roll.views])
    taken = np.stack(roll.actions)[rec]
    labels = np.stack(roll.labels)[rec]
    assert ((labels >> taken) & 1 == 0).mean() > 0.3
    assert collect(fresh(), SMALL, 5, np.arange(2)).labels is None


def test_teacher_draws_make_label_sets_of_equally_good_moves() -> None:
    """K draws under other seeds of the teacher's tie-break noise: the label is the union of
    their actions, a superset of the first draw's, larger wherever the draws disagree."""
    one = collect(fresh(), SMALL, 5, np.arange(6), teacher="team-beam")
    four = collect(fresh(), SMALL, 5, np.arange(6), teacher="team-beam", teacher_samples=4)
    rec = np.stack([v.receivers for v in one.views])
    a, b = np.stack(one.labels)[rec], np.stack(four.labels)[rec]
    np.testing.assert_array_equal(np.stack(one.actions), np.stack(four.actions))  # same episodes
    assert (a & b == a).all()  # the first draw is draw 0 of the four
    sizes = np.array([bin(int(x)).count("1") for x in b])
    assert sizes.min() >= 1 and sizes.max() <= 4 and (sizes > 1).any()
    assert (np.stack(four.labels)[~rec] == 0).all()


@pytest.mark.parametrize("name", ["commattn", "commnet"])
def test_targets_are_scored_while_the_chain_conditions_on_the_actions_taken(name: str) -> None:
    """evaluate(targets=...) gives log p(target set | s) with each CommAttn decoder step fed the
    predecessor's action as sent (the one taken), exactly what acting computed."""
    pol = fresh(name)
    state = core.reset(SMALL, 11, np.arange(5))
    core.step(SMALL, state, np.random.default_rng(0).integers(0, 9, (5, SMALL.n_robots)))
    view = batch_view(SMALL, state)
    d = pol.decide(view, greedy=False, keep_inputs=True)
    rng = np.random.default_rng(1)
    targets = rng.integers(0, 9, d.actions.shape)
    ev = pol.evaluate([view], [d.actions], [d.inputs], targets=[1 << targets])
    for k, (g, i) in enumerate(zip(ev.group, ev.robot, strict=True)):
        assert ev.logp[k].item() == pytest.approx(np.log(d.probs[g, i, targets[g, i]]), abs=1e-5)
        assert ev.agree[k] == (d.probs[g, i].argmax() == targets[g, i])
    sets = rng.integers(1, 1 << 9, d.actions.shape)  # any non-empty sets: their total probability
    ev = pol.evaluate([view], [d.actions], [d.inputs], targets=[sets])
    for k, (g, i) in enumerate(zip(ev.group, ev.robot, strict=True)):
        inset = (sets[g, i] >> np.arange(9)) & 1 == 1
        assert ev.logp[k].item() == pytest.approx(np.log(d.probs[g, i, inset].sum()), abs=1e-5)
        assert ev.agree[k] == inset[d.probs[g, i].argmax()]


def test_imitation_fits_the_teacher_on_the_states_it_saw() -> None:
    """Steps on one batch of DAgger data raise the learner's agreement with the teacher."""
    cfg = TrainConfig(policy="commattn", batch=8, imitate="central", lr=1e-2)
    pol = fresh()
    roll = collect(pol, SMALL, 5, np.arange(8), teacher="central")
    opt = torch.optim.Adam(pol.net.parameters(), lr=cfg.lr)
    parts = [update(pol, opt, roll, cfg) for _ in range(25)]
    assert parts[-1]["pg"] < 0.6 * parts[0]["pg"], (parts[0], parts[-1])
    assert parts[-1]["agree"] > parts[0]["agree"] + 0.2, (parts[0], parts[-1])


def test_train_imitate_runs_and_records_the_teacher(tmp_path: Path) -> None:
    cfg = TrainConfig(policy="commattn", epochs=1, updates=2, batch=4, threads=1,
                      val_episodes=2, curriculum_step=0, imitate="central")
    row = main(cfg, SMALL, tmp_path, console=Console(file=io.StringIO()))
    assert 0 <= row["agree"] <= 1
    assert load_checkpoint(tmp_path / "checkpoint.pt")["train"]["config"]["imitate"] == "central"


def test_teacher_draws_without_a_teacher_are_refused_in_one_line() -> None:
    with pytest.raises(ConfigError, match="imitate_samples needs a teacher"):
        dataclasses.replace(TrainConfig(), imitate_samples=4)
    for bad in (0, 17, 2.5, "4"):
        with pytest.raises(ConfigError, match="imitate_samples must lie in"):
            dataclasses.replace(TrainConfig(), imitate="team-beam", imitate_samples=bad)


@pytest.mark.parametrize("teacher", ["oracle", "commnet", "bogus"])
def test_a_teacher_that_cannot_label_is_refused_in_one_line(teacher: str) -> None:
    with pytest.raises(ConfigError, match="imitate must name a teacher") as err:
        dataclasses.replace(TrainConfig(), imitate=teacher)
    assert "\n" not in str(err.value)
