"""Episodes between the wire and the trainer: the swarm's per-robot and world records of an episode
joined into an `EpisodeRollout`, a batched `Rollout` cut into `EpisodeRollout`s (rollout
workers), and `EpisodeRollout`s stacked back into the trainer's `Rollout` (the learner).

The robots' own trajectory messages are exactly what their receivers heard, so each tick's
`View` is rebuilt bit for bit and the update is the batched trainer's own.
"""

from __future__ import annotations

import numpy as np
import torch

from policies.learned import LearnedPolicy
from swarm.learn.rollout import Rollout
from swarm.net.learning import (
    EpisodeRecord,
    EpisodeRollout,
    RobotRollout,
    check_decisions,
    heard_of,
)
from swarm.net.messages import BadMessage, Traj
from world import core
from world.config import WorldConfig
from world.decentral import TrajMessages, View


def episodes_of(roll: Rollout, version: int) -> list[EpisodeRollout]:
    """The batched trainer's rollout as one `EpisodeRollout` per group (rollout workers)."""
    out = []
    st = lambda f: np.stack([f(v) for v in roll.views])  # noqa: E731
    pos, vis = st(lambda v: v.msgs.pos), st(lambda v: v.msgs.visited)
    rec, patch = st(lambda v: v.msgs.recent), st(lambda v: v.msgs.patch)
    present, hears = st(lambda v: v.msgs.present), st(lambda v: v.hears)
    recv, last = st(lambda v: v.receivers), st(lambda v: v.last_reward)
    ok = st(lambda v: v.chain_ok if v.chain_ok is not None else np.ones_like(v.receivers))
    acts = np.stack(roll.actions)
    m = roll.metrics
    for g, ep in enumerate(roll.views[0].episodes):
        out.append(EpisodeRollout(
            ep=int(ep), seed=int(roll.views[0].seed), version=version, pos=pos[:, g],
            visited=vis[:, g], recent=rec[:, g], patch=patch[:, g], present=present[:, g],
            hears=hears[:, g], receivers=recv[:, g], chain_ok=ok[:, g],
            last_reward=last[:, g].astype(np.float32), actions=acts[:, g],
            reward=roll.reward[:, g].astype(np.float32),
            metrics=m.row(g),
            logp=None if roll.logp is None else roll.logp[:, g].astype(np.float32)))
    return out


def rollout_of(eps: list[EpisodeRollout], policy: LearnedPolicy,
               version: int | None = None) -> Rollout:
    """Stack episodes (all of the same length) into the batched trainer's `Rollout`; features and
    the baseline values b(s) are computed here with the learner's current weights. Episodes that
    carry their acting log-probabilities and were acted by a version older than `version` are
    marked stale (the update weighs them by truncated importance ratios)."""
    if not eps:
        raise ValueError("no episodes")
    ticks = eps[0].actions.shape[0]
    if any(e.actions.shape[0] != ticks for e in eps):
        raise ValueError("episodes of different lengths")
    st = lambda name, t: np.stack([getattr(e, name)[t] for e in eps])  # noqa: E731
    views = [View(seed=eps[0].seed, episodes=np.array([e.ep for e in eps], dtype=np.int64),
                  tick=t, msgs=TrajMessages(st("pos", t), st("visited", t), st("recent", t),
                                            st("patch", t), st("present", t)),
                  hears=st("hears", t), receivers=st("receivers", t),
                  last_reward=st("last_reward", t), chain_ok=st("chain_ok", t))
             for t in range(ticks)]
    policy.remember_episode(views)  # the memories each robot folded tick by tick
    actions, inputs, values = [], [], []
    for t, view in enumerate(views):
        act = st("actions", t)
        feats = policy.features(view)
        with torch.no_grad():
            ev = policy.evaluate([view], [act], [feats])
        value = np.zeros(act.shape, dtype=np.float32)
        value[ev.group, ev.robot] = ev.value.numpy()
        actions.append(act)
        inputs.append(feats)
        values.append(value)
    reward = np.stack([e.reward for e in eps], axis=1)  # [T, B, N]
    metrics = core.EpisodeMetrics.from_rows([e.metrics for e in eps])
    logp = stale = None
    if all(e.logp is not None for e in eps):
        logp = np.stack([e.logp for e in eps], axis=1)  # type: ignore[misc]
        stale = np.array([version is not None and e.version < version for e in eps])
    return Rollout(views, actions, inputs, np.stack(values), reward, metrics, logp, stale)


def join(cfg: WorldConfig, seed: int, world: EpisodeRecord,
         robots: dict[int, RobotRollout]) -> EpisodeRollout:
    """The swarm's records of one episode as an `EpisodeRollout`; BadMessage when incomplete
    (a robot that acted sent no record, or a heard message is missing), when no robot acted
    (every robot down: nothing to learn from) or a robot acted without its own message."""
    if not world.acted.any():
        raise BadMessage(f"episode {world.ep}: no robot acted")
    ticks, n = world.reward.shape
    out = EpisodeRollout(
        ep=world.ep, seed=seed, version=0, pos=np.zeros((ticks, n, 2), np.int64),
        visited=np.zeros((ticks, n, cfg.cells), bool),
        recent=np.full((ticks, n, cfg.recent_len), -1, np.int64),
        patch=np.zeros((ticks, n, cfg.vision, cfg.vision), np.uint8),
        present=np.zeros((ticks, n), bool), hears=np.zeros((ticks, n, n), bool),
        receivers=np.zeros((ticks, n), bool), chain_ok=np.ones((ticks, n), bool),
        last_reward=np.zeros((ticks, n), np.float32), actions=np.zeros((ticks, n), np.int64),
        reward=world.reward.astype(np.float32), metrics=dict(world.metrics),
        logp=np.zeros((ticks, n), np.float32))
    versions = []
    for i, rr in robots.items():
        if rr.ep != world.ep or len(rr.ticks) > ticks:
            raise BadMessage(f"robot {i}'s record does not fit episode {world.ep}")
        for traj_bytes, heard, chain_ok, action, logp, last_reward, version in rr.ticks:
            tr = Traj.unpack(traj_bytes, cfg)
            t = tr.t
            if tr.robot != i or tr.ep != world.ep or t >= ticks:
                raise BadMessage(f"robot {i}'s tick record names robot {tr.robot} tick {t}")
            out.pos[t, i] = (tr.y, tr.x)
            out.visited[t, i] = tr.visited_bits(cfg.cells)
            rec = tr.recent[-cfg.recent_len:]
            out.recent[t, i, cfg.recent_len - len(rec):] = rec
            out.patch[t, i] = np.frombuffer(tr.patch, np.uint8).reshape(cfg.vision, -1)
            out.present[t, i] = True
            out.hears[t, i] = heard_of(heard, n)
            out.chain_ok[t, i] = chain_ok
            out.actions[t, i] = action
            out.logp[t, i] = min(logp, 0.0)  # type: ignore[index]
            out.last_reward[t, i] = last_reward
            out.receivers[t, i] = bool(world.acted[t, i])
            versions.append(version)
    missing = world.acted & ~out.present
    if missing.any():
        t, i = map(int, np.argwhere(missing)[0])
        raise BadMessage(f"episode {world.ep}: robot {i} acted at tick {t} but sent no record")
    if (out.hears & ~out.present[:, None, :]).any():
        raise BadMessage(f"episode {world.ep}: a heard trajectory message is missing")
    out.receivers &= out.present
    out.version = min(versions) if versions else 0
    return check_decisions(out, every_tick=False)
