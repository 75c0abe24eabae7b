"""Batched in-process evaluation: the same world step and policies the swarm runs, B episodes
at once."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from policies.base import Policy
from swarm.net.channel import VirtualChannel
from swarm.net.faults import FaultPlan
from swarm.net.messages import Hidden, Traj
from world import core
from world.config import ConfigError, WorldConfig, check_seed
from world.decentral import View, batch_view


class ChannelFaults:
    """The radio's decisions applied to batched views, one group per episode: which trajectory
    copies each receiver hears and whether its predecessor's hidden-state message arrives, by
    the same `VirtualChannel` the world's radio runs with the virtual clock (loss, partitions,
    latency + jitter + token-bucket queues against the tick's virtual deadline, each sender's
    compute time). `hidden_floats` is the chained policy's state size (None: no chain)."""

    def __init__(self, plan: FaultPlan, cfg: WorldConfig, tick_s: float,
                 hidden_floats: int | None = None) -> None:
        self.plan, self.cfg, self.hidden_floats = plan, cfg, hidden_floats
        self.channel = VirtualChannel(plan, cfg.n_robots, tick_s)

    def _traj_sizes(self, view: View) -> np.ndarray:
        """[G, N] bytes of each sender's trajectory message, exactly as a robot packs it."""
        m, out = view.msgs, np.zeros(view.receivers.shape)
        if not self.channel.capped:
            return out
        for g, j in zip(*np.nonzero(view.receivers), strict=True):
            recent = [int(c) for c in m.recent[g, j] if c >= 0]
            out[g, j] = len(Traj(int(view.episodes[g]), view.tick, int(j), int(m.pos[g, j, 0]),
                                 int(m.pos[g, j, 1]), np.packbits(m.visited[g, j]).tobytes(),
                                 recent, m.patch[g, j].tobytes()).pack())
        return out

    def _hidden_sizes(self, view: View) -> np.ndarray:
        out = np.zeros(view.receivers.shape)
        if not self.channel.capped:
            return out
        state = bytes(4 * (self.hidden_floats or 0))
        for g, j in zip(*np.nonzero(view.receivers), strict=True):
            out[g, j] = len(Hidden(int(view.episodes[g]), view.tick, int(j), 0, state).pack())
        return out

    def apply(self, view: View) -> None:
        """Narrow `view.hears` (and set `view.chain_ok`) to what the radio delivers this tick."""
        if view.tick == 0:
            self.channel.reset(view.groups)
        if self.plan.zero:
            return
        f = self.channel.traj(view.episodes, view.tick, view.receivers, self._traj_sizes(view))
        view.hears = view.hears & f.ok
        if self.hidden_floats is None:
            return
        h = self.channel.hidden(view.episodes, view.tick, view.receivers,
                                self._hidden_sizes(view))
        pred = view.predecessor()
        g, i = np.nonzero(pred >= 0)
        ok = np.ones(pred.shape, dtype=bool)
        ok[g, i] = h.ok[g, i, pred[g, i]]
        view.chain_ok = ok


def channel_for(plan: FaultPlan | None, cfg: WorldConfig, policy: Policy,
                tick_s: float) -> ChannelFaults | None:
    """The fault model of `plan` for `policy` (None without faults)."""
    if plan is None:
        return None
    floats = getattr(policy, "state_size", None) if policy.chained else None
    return ChannelFaults(plan, cfg, tick_s, floats)


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

    def rows(self, policy: str | None = None) -> list[dict[str, object]]:
        """One row per episode: its number and metrics (`swarm eval --episodes-csv`), labelled
        `policy` (by default the result's own `.policy`)."""
        return [{"policy": self.policy if policy is None else policy, "episode": int(e),
                 **{k: getattr(self, k)[j].item() for k in core.METRIC_NAMES}}
                for j, e in enumerate(self.episodes)]

    @property
    def planning_ms_per_decision(self) -> float:
        return 1e3 * self.planning_s / max(self.decisions, 1)

    def summary(self, cfg: WorldConfig) -> dict[str, object]:
        """The contract's JSON keys (SPEC section 7) plus a few more; the figures are None
        when no episode completed (a run stopped before its first episode's end)."""
        n = len(self.episodes)

        def stat(x: np.ndarray, f: str = "mean") -> float | None:
            return float(getattr(x, f)()) if n else None

        return {
            "policy": self.policy, "robots": cfg.n_robots, "episodes": n, "seed": self.seed,
            "dynamic": cfg.dynamic, "add_every": cfg.add_every, "vision": cfg.vision,
            "comm_range": "inf" if np.isinf(cfg.comm_range) else cfg.comm_range,
            "explore_mode": cfg.explore_mode,
            "elratio_mean": stat(self.elratio), "elratio_std": stat(self.elratio, "std"),
            "reward_mean": stat(self.reward), "reward_std": stat(self.reward, "std"),
            "collisions_mean": stat(self.collisions),
            "block_collisions_mean": stat(self.block_collisions),
            "robot_collisions_mean": stat(self.robot_collisions),
            "success_rate": stat(self.success), "repeat_ratio_mean": stat(self.repeat_ratio),
            "planning_ms_per_decision": self.planning_ms_per_decision if n else None,
            "wall_s": self.wall_s,
        }

    @classmethod
    def none(cls, policy: str, seed: int, cfg: WorldConfig) -> EvalResult:
        """A result of no episode (its summary has the run's keys, its figures None)."""
        empty = np.zeros(0)
        return cls(policy, seed, empty.astype(np.int64), **{k: empty for k in core.METRIC_NAMES},
                   elratio_curve=np.zeros((0, cfg.horizon + 1)))


def acted(policy: Policy, view: View, greedy: bool = True) -> np.ndarray:
    """`policy.act(view)`, checked as the world and every robot process check it
    (`world.core.check_actions`); a policy that raises or answers no move is one line naming
    it (a ConfigError), not a traceback: a robot process would stay in place and count it."""
    try:
        out = policy.act(view, greedy=greedy)
    except ConfigError:
        raise
    except Exception as exc:  # (a plugin's bug: whatever it raises)
        raise ConfigError(f"policy {policy.name or type(policy).__name__}: act raised "
                          f"{type(exc).__name__}: {exc}") from None
    try:
        return core.check_actions(out, view.receivers.shape)
    except ValueError as exc:
        raise ConfigError(f"policy {policy.name or type(policy).__name__}: {exc}") from None


def evaluate(cfg: WorldConfig, policy: Policy, seed: int, n_episodes: int, *, batch: int = 250,
             first_episode: int = 0, greedy: bool = True, record_actions: bool = False,
             on_progress: Callable[[int], None] | None = None,
             faults: FaultPlan | None = None, tick_s: float = 2.0) -> EvalResult:
    """Run episodes first_episode .. first_episode + n_episodes - 1 of `seed` in batches.

    `faults` applies the radio's decisions of a virtual-clock run with ticks of `tick_s` virtual
    seconds (loss, partitions, latency, jitter, bandwidth queues, compute time; see
    swarm.net.channel) to every tick's view: the same as `swarm run` with that seed and plan.
    """
    check_seed(seed)
    for name, v, least in (("n_episodes", n_episodes, 1), ("batch", batch, 1),
                           ("first_episode", first_episode, 0)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < least:
            raise ConfigError(f"{name} must be an integer >= {least}, got {v!r}")
    shape = lambda c: (c.n_robots, c.vision, c.height, c.width)  # noqa: E731
    if shape(policy.cfg) != shape(cfg):
        p = policy.cfg
        raise ConfigError(f"the policy was built for {p.n_robots} robots with vision {p.vision} "
                          f"on {p.height} x {p.width}, the world has {cfg.n_robots} with "
                          f"{cfg.vision} on {cfg.height} x {cfg.width}")
    channel = channel_for(faults, cfg, policy, tick_s)
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
            if channel is not None:
                channel.apply(view)
            t0 = time.perf_counter()
            a = acted(policy, view, greedy)
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
