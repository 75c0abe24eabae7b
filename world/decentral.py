"""The decentralized view of SPEC section 3, computed once here and used by every consumer.

At tick t each robot publishes a trajectory message (its position, its own visited-cell bitmap,
its recent positions and its v x v patch), hears the messages of the robots within
`comm_range` and itself (its neighbourhood S_i(t)), and, for chained policies, takes the
decoder state of its predecessor p(i) = max{j in S_i(t), j < i}.

A `View` carries, for G groups (episodes) of N robot slots, every slot's message and who heard
whom. The batched evaluator fills every slot; a robot process fills only the messages it heard
and marks itself as the one receiver. Policies read member j's message for receiver i only where
`hears[g, i, j]`, so the two settings compute the same decision.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from world.config import WorldConfig
from world.core import Layout, WorldState, check_config, patches


@dataclass
class TrajMessages:
    """Trajectory messages of N robot slots in G groups; grid coordinates, no padding."""

    pos: np.ndarray  # [G, N, 2] int64 (y, x)
    visited: np.ndarray  # [G, N, H*W] bool: the sender's own trajectory bitmap
    recent: np.ndarray  # [G, N, L] int64 last L positions as y*W+x, oldest first, -1 none
    patch: np.ndarray  # [G, N, v, v] uint8 (see world.core.patches)
    present: np.ndarray  # [G, N] bool: the slot holds a message this tick

    @property
    def shape(self) -> tuple[int, int]:
        return self.present.shape  # type: ignore[return-value]

    def select(self, idx: np.ndarray) -> TrajMessages:
        """Messages of groups `idx`."""
        return TrajMessages(self.pos[idx], self.visited[idx], self.recent[idx], self.patch[idx],
                            self.present[idx])

    @classmethod
    def empty(cls, cfg: WorldConfig, groups: int = 1) -> TrajMessages:
        n = cfg.n_robots
        return cls(
            pos=np.zeros((groups, n, 2), dtype=np.int64),
            visited=np.zeros((groups, n, cfg.cells), dtype=bool),
            recent=np.full((groups, n, cfg.recent_len), -1, dtype=np.int64),
            patch=np.zeros((groups, n, cfg.vision, cfg.vision), dtype=np.uint8),
            present=np.zeros((groups, n), dtype=bool),
        )


def traj_messages(cfg: WorldConfig, state: WorldState) -> TrajMessages:
    """Every live robot's trajectory message at the current tick, [B, N, ...]."""
    check_config(cfg, state)
    lay = Layout.of(cfg)
    return TrajMessages(
        pos=lay.to_yx(state.pos), visited=state.visited, recent=state.recent,
        patch=patches(cfg, state), present=state.alive.copy(),
    )


def neighbourhood(comm_range: float, pos: np.ndarray, present: np.ndarray) -> np.ndarray:
    """hears[g, i, j]: robot i hears robot j (Euclidean distance <= comm_range, both present).

    pos [G, N, 2], present [G, N] -> [G, N, N] bool; a present robot always hears itself.
    """
    if np.isinf(comm_range):
        return present[:, :, None] & present[:, None, :]
    # Per-axis differences in the smallest safe integer type, squared in place: ~10x faster
    # than an int64 [G, N, N, 2] sum (this runs every tick of every batched episode).
    lo, hi = (int(pos.min()), int(pos.max())) if pos.size else (0, 0)
    dtype = np.int16 if lo >= 0 and hi < 128 else np.int32 if lo >= 0 and hi < 32768 else np.int64
    p = pos.astype(dtype)  # (hi - lo)^2 * 2 fits the chosen type
    dy = p[:, :, None, 0] - p[:, None, :, 0]
    dx = p[:, :, None, 1] - p[:, None, :, 1]
    dy *= dy
    dx *= dx
    dy += dx
    out = dy <= min(math.floor(comm_range * comm_range), int(np.iinfo(p.dtype).max))
    if not present.all():
        out &= present[:, :, None]
        out &= present[:, None, :]
    return out


def predecessor(hears: np.ndarray) -> np.ndarray:
    """p(i) = max{j in S_i, j < i}, or -1 where there is none: [G, N, N] bool -> [G, N] int64."""
    n = hears.shape[-1]
    lower = hears & np.tri(n, n, -1, dtype=bool)[None]
    rev = lower[..., ::-1]
    last = n - 1 - rev.argmax(-1)
    return np.where(lower.any(-1), last, -1)


def predecessor_of(heard: np.ndarray, robot: np.ndarray) -> np.ndarray:
    """`predecessor` of a few receivers only: their rows of `hears` [R, N] and ids [R] -> [R]."""
    n = heard.shape[-1]
    lower = heard & (np.arange(n)[None, :] < robot[:, None])
    return np.where(lower.any(-1), n - 1 - lower[:, ::-1].argmax(-1), -1)


@dataclass
class View:
    """What the receivers know at one tick; the single input of every policy's `act`."""

    seed: int
    episodes: np.ndarray  # [G] int64 episode numbers (key the counter-based noise)
    tick: int
    msgs: TrajMessages  # [G, N, ...]
    hears: np.ndarray  # [G, N, N] bool
    receivers: np.ndarray  # [G, N] bool: whose decision to compute
    last_reward: np.ndarray  # [G, N] float32 (valid for receivers)
    chain_ok: np.ndarray | None = None  # [G, N]: receiver got p(i)'s hidden-state message
    # (None: every receiver with a predecessor got it; where False a chained policy decodes as
    # if it had no predecessor, which is what a robot does when that message is lost or late)
    team_visited: np.ndarray | None = None  # [G, N, H*W] bool: each receiver's TeamMemory row
    # after this tick (set by policies that remember; None: not computed)
    belief: Any = None  # the receivers' belief maps after this tick (policies.belief.Snapshot,
    # set by learned policies that read them; None: not computed)

    @property
    def groups(self) -> int:
        return self.hears.shape[0]

    @property
    def n(self) -> int:
        return self.hears.shape[1]

    def predecessor(self) -> np.ndarray:
        """Each slot's chain predecessor p(i) [G, N] int64 (-1: none), from `hears`."""
        return predecessor(self.hears)


class TeamMemory:
    """Each receiver's memory of the team's visited cells: the OR of every visited bitmap it has
    heard this episode, its own included, [G, N, H*W].

    A sender's bitmap only grows during an episode, so the OR of what was heard is exactly the
    latest bitmap of each teammate heard at least once: a lost or out-of-range message leaves the
    receiver with that teammate's older bitmap, never with nothing. Rows of robots that are not
    receivers this tick are never touched, and a receiver's row is cleared at tick 0, so a robot
    process holding only its own row computes what the batched evaluator computes for that row.
    """

    def __init__(self, cfg: WorldConfig) -> None:
        self.cfg = cfg
        self.visited = np.zeros((0, cfg.n_robots, cfg.cells), dtype=bool)

    def reset(self, groups: int) -> None:
        self.visited = np.zeros((groups, self.cfg.n_robots, self.cfg.cells), dtype=bool)

    def update(self, view: View) -> np.ndarray:
        """Fold in the messages each receiver heard this tick; returns the rows [G, N, H*W], a
        new array each tick (never changed afterwards, so a view may keep it)."""
        if self.visited.shape[0] != view.groups:
            self.reset(view.groups)
        old = self.visited
        g, i = np.nonzero(view.receivers)
        if 4 * len(g) < old.shape[0] * old.shape[1]:  # few receivers (a robot process): their rows
            new = old.copy()
            for gg, ii in zip(g.tolist(), i.tolist(), strict=True):
                row = view.msgs.visited[gg, view.hears[gg, ii]].any(0)
                new[gg, ii] = row if view.tick == 0 else row | old[gg, ii]
            self.visited = new
            return new
        if view.tick == 0:  # a new episode, even if nobody called reset
            old = old & ~view.receivers[:, :, None]
        self.visited = old | heard_union(view)
        return self.visited


def heard_union(view: View) -> np.ndarray:
    """[G, N, H*W] bool: the union of the visited bitmaps each receiver heard this tick (its
    own included); rows of non-receivers are empty."""
    groups, n = view.receivers.shape
    g, i = np.nonzero(view.receivers)
    visited = view.msgs.visited
    if 4 * len(g) < groups * n:  # few receivers (a robot process): OR the heard bitmaps
        out = np.zeros(visited.shape, dtype=bool)
        for gg, ii in zip(g.tolist(), i.tolist(), strict=True):
            out[gg, ii] = visited[gg, view.hears[gg, ii]].any(0)
        return out
    heard = (view.hears & view.receivers[:, :, None]).astype(np.float32)  # [G, N, N]
    return np.matmul(heard, visited.astype(np.float32)) > 0


def remember(views: list[View], cfg: WorldConfig) -> None:
    """Set `team_visited` of a recorded episode batch's views (tick order, the same groups in
    each) by folding them through a fresh TeamMemory: what the acting robots computed."""
    memory = TeamMemory(cfg)
    for view in views:
        view.team_visited = memory.update(view)


def batch_view(cfg: WorldConfig, state: WorldState) -> View:
    """The view of every robot of every episode in the batch (the in-process evaluator's view)."""
    msgs = traj_messages(cfg, state)
    hears = neighbourhood(cfg.comm_range, msgs.pos, msgs.present)
    return View(seed=state.seed, episodes=state.episodes, tick=state.t, msgs=msgs, hears=hears,
                receivers=state.alive.copy(), last_reward=state.last_reward)


def robot_view(cfg: WorldConfig, seed: int, episode: int, tick: int, robot: int,
               heard: TrajMessages, last_reward: float) -> View:
    """The view of one robot that heard `heard` ([1, N, ...], its own message included)."""
    n = cfg.n_robots
    hears = np.zeros((1, n, n), dtype=bool)
    hears[0, robot] = heard.present[0]
    receivers = np.zeros((1, n), dtype=bool)
    receivers[0, robot] = True
    reward = np.zeros((1, n), dtype=np.float32)
    reward[0, robot] = last_reward
    return View(seed=seed, episodes=np.array([episode], dtype=np.int64), tick=tick, msgs=heard,
                hears=hears, receivers=receivers, last_reward=reward)


def heard_by(cfg: WorldConfig, view: View, g: int, robot: int) -> TrajMessages:
    """The messages robot `robot` of group `g` heard, as a [1, N, ...] bundle (others blanked)."""
    m = view.msgs.select(np.array([g]))
    mask = view.hears[g, robot]
    blank = ~mask
    m.pos = m.pos.copy()
    m.visited = m.visited.copy()
    m.recent = m.recent.copy()
    m.patch = m.patch.copy()
    m.pos[0, blank] = 0
    m.visited[0, blank] = False
    m.recent[0, blank] = -1
    m.patch[0, blank] = 0
    m.present = mask[None].copy()
    return m
