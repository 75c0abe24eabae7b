"""`swarm train --algo ppo`: GAE advantages and the clipped surrogate (ours, beside the paper's
REINFORCE), in one process and split over workers."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import numpy as np
import pytest
import torch
from rich.console import Console

from policies import make_policy
from swarm.learn.config import TrainConfig
from swarm.learn.rollout import collect
from swarm.learn.trainer import main
from swarm.learn.update import advantages, backward, gae, normaliser, returns, update
from world.config import ConfigError, WorldConfig

SMALL = WorldConfig(height=8, width=8, n_static=6, n_dynamic=4, n_robots=4, horizon=8, add_every=2,
                    vision=3, comm_range=3.0, recent_len=4)


def fresh(seed: int = 0):
    torch.manual_seed(seed)
    return make_policy("commattn", SMALL)


def test_gae_by_hand_and_its_two_limits() -> None:
    r = np.array([[1.0], [0.0], [2.0]])
    v = np.array([[0.5], [1.0], [0.25]])
    g, lam = 0.9, 0.5
    d = [1.0 + g * 1.0 - 0.5, 0.0 + g * 0.25 - 1.0, 2.0 - 0.25]  # TD errors
    want = [d[0] + g * lam * (d[1] + g * lam * d[2]), d[1] + g * lam * d[2], d[2]]
    np.testing.assert_allclose(gae(r, v, g, lam)[:, 0], want)
    rng = np.random.default_rng(0)
    r, v = rng.normal(size=(7, 3, 4)), rng.normal(size=(7, 3, 4))
    np.testing.assert_allclose(gae(r, v, 0.9, 1.0), returns(r, 0.9) - v, atol=1e-12)
    td = r + 0.9 * np.concatenate([v[1:], np.zeros((1, 3, 4))]) - v
    np.testing.assert_allclose(gae(r, v, 0.9, 0.0), td, atol=1e-12)


def test_the_first_ppo_pass_is_the_policy_gradient_on_the_same_advantages() -> None:
    """At the weights that acted rho = 1, so the clipped surrogate's gradient is A grad log pi:
    the same gradient as REINFORCE's on GAE's advantages."""
    ppo = TrainConfig(policy="commattn", batch=6, algo="ppo", gamma=0.9)
    roll = collect(fresh(), SMALL, 5, np.arange(6))
    adv = advantages(roll, ppo)
    mean, std, n = normaliser([adv.moments()])
    grads = []
    for cfg in (ppo, dataclasses.replace(ppo, algo="reinforce")):
        pol = fresh()
        pol.net.zero_grad(set_to_none=True)
        parts = backward(pol, roll, adv, cfg, mean, std, n)
        grads.append([p.grad.clone() for p in pol.net.parameters() if p.grad is not None])
    assert parts["pg"] != 0
    for a, b in zip(*grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)


def test_ppo_takes_its_passes_and_the_clip_binds_after_big_steps() -> None:
    roll = collect(fresh(), SMALL, 5, np.arange(6))
    after = {}
    for epochs in (1, 3):
        cfg = TrainConfig(policy="commattn", batch=6, algo="ppo", ppo_epochs=epochs, lr=0.05,
                          max_grad_norm=0)
        pol = fresh()
        opt = torch.optim.Adam(pol.net.parameters(), lr=cfg.lr)
        parts = update(pol, opt, roll, cfg)
        after[epochs] = {k: v.clone() for k, v in pol.net.state_dict().items()}
        if epochs == 3:
            assert 0 < parts["clip_frac"] <= 1  # the later passes left the trust region
    assert any(not torch.equal(after[1][k], after[3][k]) for k in after[1])


@pytest.mark.procs
def test_parallel_ppo_equals_single_process_ppo() -> None:
    from swarm.learn.parallel import ParallelUpdater

    cfg = TrainConfig(policy="commattn", batch=9, algo="ppo", ppo_epochs=2)
    single = fresh()
    opt1 = torch.optim.Adam(single.net.parameters(), lr=1e-3)
    parts1 = update(single, opt1, collect(single, SMALL, 5, np.arange(9)), cfg)
    split_pol = fresh()
    opt2 = torch.optim.Adam(split_pol.net.parameters(), lr=1e-3)
    with ParallelUpdater(split_pol, SMALL, workers=2, threads=1) as pool:
        _, parts2 = pool.update(split_pol, opt2, SMALL, 5, np.arange(9), cfg)
    for key in ("loss", "pg", "baseline", "entropy", "clip_frac"):
        assert parts2[key] == pytest.approx(parts1[key], rel=1e-4, abs=1e-6), key
    one, two = single.net.state_dict(), split_pol.net.state_dict()
    for key in one:  # two Adam steps: its per-weight scaling magnifies float rounding of tiny grads
        torch.testing.assert_close(two[key], one[key], rtol=1e-4, atol=2e-5)


def test_train_ppo_runs(tmp_path: Path) -> None:
    cfg = TrainConfig(policy="commattn", epochs=1, updates=2, batch=4, threads=1,
                      val_episodes=0, curriculum_step=0, algo="ppo", ppo_epochs=2)
    row = main(cfg, SMALL, tmp_path, console=Console(file=io.StringIO()))
    assert np.isfinite(row["loss"]) and 0 <= row["clip_frac"] <= 1


@pytest.mark.parametrize("changes, match", [({"algo": "a2c"}, "algo must be"),
                                            ({"algo": "ppo", "imitate": "central"}, "imitate"),
                                            ({"algo": "ppo", "ppo_epochs": 0}, "ppo_epochs")])
def test_bad_ppo_settings_are_one_line_errors(changes: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as err:
        dataclasses.replace(TrainConfig(), **changes)
    assert "\n" not in str(err.value)
