"""The REINFORCE update with the state-specific baseline (paper sections 3 and 4.3), and PPO.

Per robot j and tick t the return G_t = sum_{k >= t} gamma^(k - t) r_k; the loss is the paper's

    loss_j = sum_t [ -log p(a_t | s_t) (G_t - b(s_t)) + alpha (G_t - b(s_t))^2 ]

summed over robots and averaged over decisions, with b detached in the first term, plus an
optional entropy bonus; stale episodes (acted by older weights) are weighted by truncated
importance ratios. `backward` is split from `step` so data-parallel parts add up exactly.

With `algo = "ppo"` (ours, not the paper's) the advantages are GAE's, the policy term is the
clipped surrogate -min(rho A, clip(rho) A) with rho = pi(a) / pi_acted(a), and `ppo_epochs`
steps are taken on each batch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from policies.learned import LearnedPolicy
from swarm.learn.config import TrainConfig
from swarm.learn.rollout import Rollout


def returns(reward: np.ndarray, gamma: float) -> np.ndarray:
    """G_t = r_t + gamma G_{t+1} along axis 0."""
    out = np.zeros_like(reward, dtype=np.float64)
    acc = np.zeros(reward.shape[1:])
    for t in range(reward.shape[0] - 1, -1, -1):
        acc = reward[t] + gamma * acc
        out[t] = acc
    return out


# --------------------------------------------------------------------------------------- loss
@dataclass
class Advantages:
    """Returns and raw advantages of a rollout, arrays [T, B, N], and the live decisions."""

    ret: np.ndarray
    adv: np.ndarray
    live: np.ndarray

    def moments(self) -> tuple[float, float, int]:
        """(sum, sum of squares, count) of the live advantages: what batch normalisation needs
        from each part of a batch split across processes."""
        a = self.adv[self.live]
        return float(a.sum()), float((a * a).sum()), int(a.size)


def gae(reward: np.ndarray, value: np.ndarray, gamma: float, lam: float) -> np.ndarray:
    """Generalized advantage estimates along axis 0 (Schulman et al. 2016): A_t = sum_k
    (gamma lam)^k delta_{t+k}, delta_t = r_t + gamma V(s_{t+1}) - V(s_t), V = 0 after the last
    tick (episodes end at the horizon). lam = 1 gives G_t - V(s_t), lam = 0 the TD error."""
    out = np.zeros_like(reward, dtype=np.float64)
    acc = np.zeros(reward.shape[1:])
    next_v = np.zeros(reward.shape[1:])
    for t in range(reward.shape[0] - 1, -1, -1):
        acc = reward[t] + gamma * next_v - value[t] + gamma * lam * acc
        out[t] = acc
        next_v = value[t]
    return out


def advantages(roll: Rollout, cfg: TrainConfig) -> Advantages:
    live = np.stack([v.receivers for v in roll.views])
    if cfg.algo == "ppo":  # the baseline fits the GAE returns A + V
        adv = gae(roll.reward * cfg.reward_scale, roll.value.astype(np.float64), cfg.gamma,
                  cfg.gae_lambda)
        return Advantages(adv + roll.value, adv, live)
    ret = returns(roll.reward * cfg.reward_scale, cfg.gamma)
    return Advantages(ret, ret - roll.value, live)


def normaliser(moments: list[tuple[float, float, int]]) -> tuple[float, float, int]:
    """(mean, std, count) of the advantages of a whole batch from its parts' moments."""
    s1 = sum(m[0] for m in moments)
    s2 = sum(m[1] for m in moments)
    n = sum(m[2] for m in moments)
    mean = s1 / max(n, 1)
    return mean, math.sqrt(max(s2 / max(n, 1) - mean * mean, 0.0)), n


def backward(policy: LearnedPolicy, roll: Rollout, adv: Advantages, cfg: TrainConfig,
             mean: float, std: float, decisions: int) -> dict[str, float]:
    """Accumulate the gradient of this rollout's share of the loss into the parameters' .grad.

    `decisions` counts the whole batch's decisions and (mean, std) are its advantages' moments,
    so the parts of a batch split across processes add up to the gradient of the whole.
    """
    imitate = roll.labels is not None  # DAgger: every decision weighs 1 on the teacher's action
    if imitate:
        a_all = np.ones_like(adv.adv)
    else:
        a_all = (adv.adv - mean) / (std + 1e-8) if cfg.adv_norm else adv.adv
    totals = {"loss": 0.0, "pg": 0.0, "baseline": 0.0, "entropy": 0.0}
    if imitate:
        totals["agree"] = 0.0  # decisions where the learner's greedy action is the teacher's
    for t0 in range(0, len(roll.views), cfg.chunk_ticks):
        span = slice(t0, t0 + cfg.chunk_ticks)
        ev = policy.evaluate(roll.views[span], roll.actions[span], roll.inputs[span],
                             targets=roll.labels[span] if roll.labels is not None else None)
        at = (t0 + ev.tick, ev.group, ev.robot)
        a = torch.from_numpy(a_all[at].astype(np.float32))
        if imitate and ev.agree is not None:
            totals["agree"] += float(ev.agree.sum()) / decisions
        g = torch.from_numpy(adv.ret[at].astype(np.float32))
        if cfg.algo == "ppo":  # clipped surrogate on the ratio to the weights that acted
            if roll.logp is None:
                raise ValueError("PPO needs the log-probabilities recorded while acting")
            acted = torch.from_numpy(roll.logp[at].astype(np.float32))
            rho = torch.exp(ev.logp - acted)
            lo, hi = 1.0 - cfg.ppo_clip, 1.0 + cfg.ppo_clip
            surr = torch.minimum(rho * a, rho.clamp(lo, hi) * a)
            clipped = ((rho.detach() < lo) & (a < 0)) | ((rho.detach() > hi) & (a > 0))
            totals["clip_frac"] = totals.get("clip_frac", 0.0) + float(clipped.sum()) / decisions
            pg = -surr.sum() / decisions
        elif not imitate and roll.stale is not None and roll.logp is not None and \
                cfg.is_clip > 0:
            stale = torch.from_numpy(roll.stale[ev.group])  # their decisions: truncated IS weight
            if bool(stale.any()):
                acted = torch.from_numpy(roll.logp[at].astype(np.float32))
                rho = torch.exp(ev.logp.detach() - acted)
                w = torch.where(stale, rho.clamp(max=cfg.is_clip), 1.0)
                a = a * w
                totals["is_weight"] = totals.get("is_weight", 0.0) + float(w[stale].sum())
                totals["stale_decisions"] = totals.get("stale_decisions", 0.0) + float(
                    stale.sum())
            pg = -(ev.logp * a).sum() / decisions
        else:
            pg = -(ev.logp * a).sum() / decisions
        base = cfg.alpha * ((g - ev.value) ** 2).sum() / decisions
        ent = ev.entropy.sum() / decisions
        loss = pg + base - cfg.ent_coef * ent
        loss.backward()
        for key, val in (("loss", loss), ("pg", pg), ("baseline", base), ("entropy", ent)):
            totals[key] += val.item()
    return totals


def step(policy: LearnedPolicy, opt: torch.optim.Optimizer, cfg: TrainConfig) -> float:
    """Clip the accumulated gradient, take the optimizer step; returns the gradient norm."""
    params = [p for p in policy.net.parameters() if p.grad is not None]
    clip = cfg.max_grad_norm if cfg.max_grad_norm > 0 else math.inf
    norm = torch.nn.utils.clip_grad_norm_(params, clip)
    opt.step()
    return float(norm)


def update(policy: LearnedPolicy, opt: torch.optim.Optimizer, roll: Rollout,
           cfg: TrainConfig) -> dict[str, float]:
    """One REINFORCE step on a rollout; returns the loss parts per decision.

    The loss is the paper's sum over robots and ticks divided by the number of decisions in the
    batch (a constant scale, so that gradient clipping means the same for any batch size).
    """
    adv = advantages(roll, cfg)
    mean, std, decisions = normaliser([adv.moments()])
    passes = []
    for _ in range(cfg.ppo_epochs if cfg.algo == "ppo" else 1):
        opt.zero_grad(set_to_none=True)
        totals = backward(policy, roll, adv, cfg, mean, std, decisions)
        totals["grad_norm"] = step(policy, opt, cfg)
        passes.append(totals)
    if totals.get("stale_decisions"):  # the mean importance weight of the stale decisions
        totals["is_weight"] /= totals["stale_decisions"]
    return merge_passes(passes)


def merge_passes(passes: list[dict[str, float]]) -> dict[str, float]:
    """One row for the log from PPO's passes over a batch: the first pass's losses (those of
    the weights that acted), the last pass's clipped fraction (how far the steps went)."""
    out = dict(passes[0])
    if len(passes) > 1:
        out["clip_frac"] = passes[-1].get("clip_frac", 0.0)
        out["grad_norm"] = float(np.mean([p["grad_norm"] for p in passes]))
    return out

