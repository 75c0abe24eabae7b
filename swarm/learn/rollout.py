"""Batched rollouts: episodes run to the horizon on the world core with sampled actions (the
counter-based noise the evaluator and the swarm use), recorded in the form the update needs."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

import numpy as np

from policies import make_policy
from policies.infer.tokens import Tokens
from policies.learned import LearnedPolicy
from swarm.learn.config import TrainConfig
from swarm.learn.evaluate import channel_for
from swarm.net.faults import FaultPlan, plan_from_table
from world import core
from world.config import WorldConfig
from world.decentral import TrajMessages, View, batch_view


@dataclass
class Rollout:
    """One batch of finished episodes, arrays [T, B, N] unless noted."""

    views: list[View]
    actions: list[np.ndarray]  # T of [B, N]
    inputs: list[Tokens]  # T features computed at acting time (reused by the update)
    value: np.ndarray  # b(s) at acting time (for the advantage)
    reward: np.ndarray
    metrics: core.EpisodeMetrics
    logp: np.ndarray | None = None  # log pi(a) under the weights that acted (0 off receivers)
    stale: np.ndarray | None = None  # [B] bool: acted by older weights than the learner's now
    labels: list[np.ndarray] | None = None  # T of [B, N]: a teacher's actions (--imitate)


def frozen(view: View) -> View:
    """A copy of a view that later world steps cannot change (the core mutates state in place)."""
    m = view.msgs
    msgs = TrajMessages(m.pos.copy(), m.visited.copy(), m.recent.copy(), m.patch.copy(),
                        m.present.copy())
    return dataclasses.replace(view, episodes=view.episodes.copy(), msgs=msgs,
                               receivers=view.receivers.copy(), last_reward=view.last_reward.copy())


def train_faults(cfg: TrainConfig) -> FaultPlan | None:
    """The radio's fault model applied during rollouts: `faults` (the run's fault flags) and
    `--train-loss`, with its own seed unless the table names one."""
    table = dict(json.loads(cfg.faults)) if cfg.faults else {}
    if cfg.train_loss > 0:
        table["loss"] = cfg.train_loss
    if not table:
        return None
    table.setdefault("seed", cfg.seed + 3_000_000)
    return plan_from_table(table)


def collect(policy: LearnedPolicy, world: WorldConfig, seed: int, episodes: np.ndarray,
            faults: FaultPlan | None = None, tick_s: float = 2.0, teacher: str = "") -> Rollout:
    """Run `episodes` of `seed` to the horizon with sampled actions (under the radio's `faults`
    in virtual time, ticks of `tick_s`); with a `teacher` policy, its action at every view is
    recorded as the label (the learner's actions still drive the episodes)."""
    channel = channel_for(faults, world, policy, tick_s)
    state = core.reset(world, seed, episodes)
    policy.reset(len(episodes))
    guide = make_policy(teacher, world) if teacher else None
    if guide is not None:
        guide.reset(len(episodes))
    labels: list[np.ndarray] = []
    views, actions, inputs, values, rewards, logp = [], [], [], [], [], []
    while not state.done:
        view = frozen(batch_view(world, state))
        if channel is not None:
            channel.apply(view)  # the swarm radio's message faults, during training
        d = policy.decide(view, greedy=False, keep_inputs=True)
        if guide is not None:
            labels.append(guide.act(view, greedy=True))
        rewards.append(core.step(world, state, d.actions))
        views.append(view)
        actions.append(d.actions)
        inputs.append(d.inputs)
        values.append(d.value)
        p = np.take_along_axis(d.probs, d.actions[..., None], -1)[..., 0]
        logp.append(np.log(np.maximum(p, 1e-30), dtype=np.float32) * view.receivers)
    return Rollout(views, actions, inputs, np.stack(values), np.stack(rewards),
                   core.metrics(world, state), np.stack(logp),
                   labels=labels if guide is not None else None)

