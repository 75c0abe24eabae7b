"""Batched in-process evaluation: the same world step and policies the swarm runs, B episodes
at once."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from policies.base import Policy
from swarm.net.faults import KIND_HIDDEN, KIND_TRAJ, FaultPlan, delivery_mask
from world import core
from world.config import WorldConfig
from world.decentral import View, batch_view


def apply_faults(view: View, faults: FaultPlan) -> None:
    """Drop the trajectory and hidden-state messages the radio would drop at this tick."""
    n = view.n
    view.hears = view.hears & delivery_mask(faults, view.episodes, view.tick, n, KIND_TRAJ)
    pred = view.predecessor()
    hidden = delivery_mask(faults, view.episodes, view.tick, n, KIND_HIDDEN)
    g, i = np.nonzero(pred >= 0)
    ok = np.ones(pred.shape, dtype=bool)
    ok[g, i] = hidden[g, i, pred[g, i]]
    view.chain_ok = ok


@dataclass
class EvalResult:
    """Per-episode metrics of an evaluation, arrays [episodes]."""

    policy: str
    seed: int
    episodes: np.ndarray
    reward: np.ndarray
    collisions: np.ndarray
    block_collisions: np.ndarray
    robot_collisions: np.ndarray
    elratio: np.ndarray
    success: np.ndarray
    repeat_ratio: np.ndarray
    elratio_curve: np.ndarray  # [episodes, T+1]
    planning_s: float = 0.0  # wall seconds inside policy.act
    decisions: int = 0  # (episode, tick) decisions of the whole team
    wall_s: float = 0.0
    actions: list[np.ndarray] = field(default_factory=list)  # [T] of [episodes, N] when recorded

    @classmethod
    def of(cls, policy: str, seed: int, episodes: np.ndarray, parts: list[core.EpisodeMetrics],
           curves: list[np.ndarray], **timing: Any) -> EvalResult:
        """The one way a result is made, by the batched evaluator and by the world process alike:
        from the world core's `EpisodeMetrics` of each batch and the elratio curves [B, T+1]."""
        m = core.EpisodeMetrics.concat(parts)
        return cls(policy=policy, seed=seed, episodes=episodes,
                   **{k: getattr(m, k) for k in core.METRIC_NAMES},
                   elratio_curve=np.concatenate(curves), **timing)

    @property
    def planning_ms_per_decision(self) -> float:
        return 1e3 * self.planning_s / max(self.decisions, 1)

    def summary(self, cfg: WorldConfig) -> dict[str, object]:
        """The contract's JSON keys (SPEC section 7) plus a few more."""
        n = len(self.episodes)
        return {
            "policy": self.policy, "robots": cfg.n_robots, "episodes": n, "seed": self.seed,
            "dynamic": cfg.dynamic, "add_every": cfg.add_every, "vision": cfg.vision,
            "comm_range": "inf" if np.isinf(cfg.comm_range) else cfg.comm_range,
            "explore_mode": cfg.explore_mode,
            "elratio_mean": float(self.elratio.mean()), "elratio_std": float(self.elratio.std()),
            "reward_mean": float(self.reward.mean()), "reward_std": float(self.reward.std()),
            "collisions_mean": float(self.collisions.mean()),
            "block_collisions_mean": float(self.block_collisions.mean()),
            "robot_collisions_mean": float(self.robot_collisions.mean()),
            "success_rate": float(self.success.mean()),
            "repeat_ratio_mean": float(self.repeat_ratio.mean()),
            "planning_ms_per_decision": self.planning_ms_per_decision,
            "wall_s": self.wall_s,
        }


def evaluate(cfg: WorldConfig, policy: Policy, seed: int, n_episodes: int, *, batch: int = 250,
             first_episode: int = 0, greedy: bool = True, record_actions: bool = False,
             on_progress: Callable[[int], None] | None = None,
             faults: FaultPlan | None = None) -> EvalResult:
    """Run episodes first_episode .. first_episode + n_episodes - 1 of `seed` in batches.

    `faults` applies the radio's message faults that do not depend on wall time (loss,
    partition; the same seeded draws as the swarm's radio) to every tick's view.
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    parts: list[core.EpisodeMetrics] = []
    curves: list[np.ndarray] = []
    actions: list[list[np.ndarray]] = []
    planning = 0.0
    decisions = 0
    start = time.perf_counter()
    for lo in range(first_episode, first_episode + n_episodes, batch):
        eps = np.arange(lo, min(lo + batch, first_episode + n_episodes))
        state = core.reset(cfg, seed, eps)
        policy.reset(len(eps))
        acts = []
        while not state.done:
            view = batch_view(cfg, state)
            if faults is not None and not faults.zero:
                apply_faults(view, faults)
            t0 = time.perf_counter()
            a = policy.act(view, greedy=greedy)
            planning += time.perf_counter() - t0
            decisions += len(eps)
            if record_actions:
                acts.append(a.copy())
            core.step(cfg, state, a)
        parts.append(core.metrics(cfg, state))
        curves.append(state.elratio.copy())
        actions.append(acts)
        if on_progress is not None:
            on_progress(len(eps))
    rec = ([np.concatenate([a[t] for a in actions]) for t in range(cfg.horizon)]
           if record_actions else [])
    return EvalResult.of(policy.name, seed, np.arange(first_episode, first_episode + n_episodes),
                         parts, curves, planning_s=planning, decisions=decisions,
                         wall_s=time.perf_counter() - start, actions=rec)
