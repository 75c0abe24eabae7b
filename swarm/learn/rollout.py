"""Batched rollouts: episodes run to the horizon on the world core with sampled actions (the
counter-based noise the evaluator and the swarm use), recorded in the form the update needs."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

import numpy as np

from policies import make_policy
from policies.base import Policy
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
    labels: list[np.ndarray] | None = None  # T of [B, N] uint16: bit a set where a teacher chose a


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


TEACHER_SEED_STEP = 1_000_003  # teacher draw k sees the view's seed + k * this (its noise only)


def teacher_labels(guides: list[Policy], view: View) -> np.ndarray:
    """Label sets [G, N] uint16 of one view: bit a set where a teacher draw chose action a (draw
    k acts on the view with its seed moved by k steps, so only its tie-break noise differs)."""
    mask = np.zeros(view.receivers.shape, dtype=np.uint16)
    for k, guide in enumerate(guides):
        seen = view if k == 0 else dataclasses.replace(view, seed=view.seed + k * TEACHER_SEED_STEP)
        mask |= (np.uint16(1) << guide.act(seen, greedy=True).astype(np.uint16))
    return np.where(view.receivers, mask, np.uint16(0))


def collect(policy: LearnedPolicy, world: WorldConfig, seed: int, episodes: np.ndarray,
            faults: FaultPlan | None = None, tick_s: float = 2.0, teacher: str = "",
            teacher_samples: int = 1) -> Rollout:
    """Run `episodes` of `seed` to the horizon with sampled actions (under the radio's `faults`
    in virtual time, ticks of `tick_s`); with a `teacher` policy, the set of its actions at every
    view over `teacher_samples` draws is recorded as the label (the learner's actions still
    drive the episodes)."""
    channel = channel_for(faults, world, policy, tick_s)
    state = core.reset(world, seed, episodes)
    policy.reset(len(episodes))
    guides = [make_policy(teacher, world) for _ in range(teacher_samples)] if teacher else []
    for guide in guides:
        guide.reset(len(episodes))
    labels: list[np.ndarray] = []
    views, actions, inputs, values, rewards, logp = [], [], [], [], [], []
    while not state.done:
        view = frozen(batch_view(world, state))
        if channel is not None:
            channel.apply(view)  # the swarm radio's message faults, during training
        d = policy.decide(view, greedy=False, keep_inputs=True)
        if guides:
            labels.append(teacher_labels(guides, view))
        rewards.append(core.step(world, state, d.actions))
        views.append(view)
        actions.append(d.actions)
        inputs.append(d.inputs)
        values.append(d.value)
        p = np.take_along_axis(d.probs, d.actions[..., None], -1)[..., 0]
        logp.append(np.log(np.maximum(p, 1e-30), dtype=np.float32) * view.receivers)
    return Rollout(views, actions, inputs, np.stack(values), np.stack(rewards),
                   core.metrics(world, state), np.stack(logp),
                   labels=labels if guides else None)

