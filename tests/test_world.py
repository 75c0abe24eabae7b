"""Property and hand-built tests of the world's rules (SPEC section 2) and decentralized view (3).

The centrepiece is `RefWorld`: a slow, per-robot Python loop version of one step, written from
the SPEC alone, that the vectorized `world.core.step` must match exactly on random states.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from world import core
from world.config import SEED_MAX, ConfigError, WorldConfig, load_toml
from world.decentral import (
    TeamMemory,
    batch_view,
    heard_by,
    neighbourhood,
    predecessor,
    predecessor_of,
    robot_view,
)
from world.noise import uniform

Cell = tuple[int, int]
SLOW = [HealthCheck.too_slow]  # a busy 2-core CI box must not fail a test for being slow

# SPEC: 9 actions = stay + 8 neighbours, in core's order: stay, N, NE, E, SE, S, SW, W, NW.
MOVES: list[Cell] = [(0, 0), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1)]
STAY, N, NE, E, SE, S, SW, W, NW = range(9)


def due_steps(cfg: WorldConfig) -> list[int]:
    """SPEC schedule: batches of n = ceil(K / floor(0.9 T / m)) every m steps, first at step m."""
    k = cfg.n_dynamic if cfg.dynamic else 0
    if k == 0:
        return []
    batches = (9 * cfg.horizon) // (10 * cfg.add_every)  # floor(0.9 T / m) in exact integers
    n = -(-k // batches)
    return [(i // n + 1) * cfg.add_every for i in range(k)]


@dataclass
class RefWorld:
    """One episode of SPEC section 2, as plain Python sets and loops."""

    cfg: WorldConfig
    blocks: set[Cell]
    dyn: list[Cell]
    pos: list[Cell]
    due: list[int] = field(default_factory=list)
    active: list[bool] = field(default_factory=list)
    explored: set[Cell] = field(default_factory=set)
    visited: list[set[Cell]] = field(default_factory=list)
    trail: list[list[Cell]] = field(default_factory=list)
    t: int = 0
    block_coll: list[int] = field(default_factory=list)
    robot_coll: list[int] = field(default_factory=list)
    elratios: list[float] = field(default_factory=list)
    success: bool = False

    def __post_init__(self) -> None:
        n = len(self.pos)
        self.due = due_steps(self.cfg)
        self.active = [False] * len(self.dyn)
        self.visited = [{p} for p in self.pos]
        self.trail = [[p] for p in self.pos]
        self.block_coll = [0] * n
        self.robot_coll = [0] * n
        for p in self.pos:
            self.explored |= self.seen_from(p) if self.sense else {p}
        self.elratios = [self.elratio()]

    @property
    def sense(self) -> bool:
        return self.cfg.explore_mode == "sense"

    def in_grid(self, c: Cell) -> bool:
        return 0 <= c[0] < self.cfg.height and 0 <= c[1] < self.cfg.width

    def blocked(self, c: Cell) -> bool:
        """Off-grid, static block or active dynamic block."""
        return (not self.in_grid(c) or c in self.blocks
                or any(a and d == c for a, d in zip(self.active, self.dyn, strict=True)))

    def seen_from(self, c: Cell) -> set[Cell]:
        r = self.cfg.vision // 2
        return {(c[0] + dy, c[1] + dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1)
                if self.in_grid((c[0] + dy, c[1] + dx))}

    def elratio(self) -> float:
        on = {d for a, d in zip(self.active, self.dyn, strict=True) if a}
        covered = self.explored | self.blocks | on
        return len(covered) / (self.cfg.height * self.cfg.width)

    def patch(self, i: int) -> np.ndarray:
        """Robot i's v x v view: 0 free, 1 block, 2 off-grid, +4 when a robot stands there."""
        r = self.cfg.vision // 2
        y, x = self.pos[i]
        out = np.zeros((self.cfg.vision, self.cfg.vision), dtype=np.uint8)
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                c = (y + dy, x + dx)
                code = 2 if not self.in_grid(c) else (1 if self.blocked(c) else 0)
                out[dy + r, dx + r] = code + (4 if c in self.pos else 0)
        return out

    def step(self, actions: list[int]) -> list[float]:
        cfg = self.cfg
        n = len(self.pos)
        before = set(self.explored)
        # 1. robots move; a refused move is one block collision
        block_hit = [False] * n
        for i, a in enumerate(actions):
            dy, dx = MOVES[a]
            target = (self.pos[i][0] + dy, self.pos[i][1] + dx)
            if a != STAY and self.blocked(target):
                block_hit[i] = True
            else:
                self.pos[i] = target
        # 2. every robot sharing its cell with another counts one robot collision
        robot_hit = [any(j != i and self.pos[j] == self.pos[i] for j in range(n)) for i in range(n)]
        # 3. B_back against the explored set before this step
        back = []
        for i in range(n):
            if self.sense:
                back.append(not (self.seen_from(self.pos[i]) - before))
            else:
                back.append(self.pos[i] in before)
        # 4. explored set updated
        for i in range(n):
            self.explored |= self.seen_from(self.pos[i]) if self.sense else {self.pos[i]}
            self.visited[i].add(self.pos[i])
            self.trail[i].append(self.pos[i])
        # 5. pending dynamic blocks due by now activate where no robot stands
        self.t += 1
        for k, cell in enumerate(self.dyn):
            if not self.active[k] and self.due[k] <= self.t and cell not in self.pos:
                self.active[k] = True
        # 6. elratio, rewards
        self.elratios.append(self.elratio())
        rewards = []
        for i in range(n):
            self.block_coll[i] += block_hit[i]
            self.robot_coll[i] += robot_hit[i]
            rewards.append(back[i] * cfg.r_back + (block_hit[i] + robot_hit[i]) * cfg.r_coll)
        if self.t == cfg.horizon:
            self.success = (self.elratios[-1] >= cfg.success_elratio
                            and sum(self.block_coll) <= cfg.success_max_block_collisions)
            rewards = [r + (cfg.r_succ if self.success else cfg.r_fail) for r in rewards]
        return rewards


def ref_of(cfg: WorldConfig, blocks: np.ndarray, starts: np.ndarray, dyn: np.ndarray) -> RefWorld:
    return RefWorld(cfg, {(int(y), int(x)) for y, x in np.argwhere(blocks)},
                    [(int(y), int(x)) for y, x in dyn], [(int(y), int(x)) for y, x in starts])


def assert_matches(cfg: WorldConfig, state: core.WorldState, b: int, ref: RefWorld) -> None:
    """Episode b of the vectorized state equals the reference in everything a user can see."""
    lay = core.Layout.of(cfg)
    assert state.t == ref.t
    assert [tuple(c) for c in lay.to_yx(state.pos[b]).tolist()] == ref.pos
    explored = {(y, x) for y, x in np.argwhere(lay.inner(state.explored[b])).tolist()}
    assert explored == ref.explored
    assert state.dyn_active[b].tolist() == ref.active
    grid = lay.inner(state.grid[b])
    dyn_on = {(y, x) for y, x in np.argwhere(grid == core.DYNAMIC).tolist()}
    assert dyn_on == {d for a, d in zip(ref.active, ref.dyn, strict=True) if a}
    assert state.block_coll[b].tolist() == ref.block_coll
    assert state.robot_coll[b].tolist() == ref.robot_coll
    assert state.elratio[b, :state.t + 1].tolist() == ref.elratios
    pat = core.patches(cfg, state)[b]
    for i in range(cfg.n_robots):
        np.testing.assert_array_equal(pat[i], ref.patch(i))
        cells = {(c // cfg.width, c % cfg.width) for c in np.flatnonzero(state.visited[b, i])}
        assert cells == ref.visited[i]
        tail = ref.trail[i][-cfg.recent_len:]
        expect = [-1] * (cfg.recent_len - len(tail)) + [y * cfg.width + x for y, x in tail]
        assert state.recent[b, i].tolist() == expect
    if state.done:
        assert bool(state.success[b]) == ref.success


Episode = tuple[np.ndarray, np.ndarray, np.ndarray]  # static blocks, starts, dynamic cells
Scenario = tuple[WorldConfig, list[Episode], np.ndarray]


@st.composite
def scenarios(draw: st.DrawFn, crowded: bool = False) -> Scenario:
    """A small config, B episodes (generated or arbitrary random maps) and T x [B, N] actions.

    `crowded`: 3 x 3 to 4 x 4 grids packed with robots and dynamic blocks, so that overlaps,
    refused moves and blocks pending under robots are the rule rather than the exception.
    """
    side = (3, 4) if crowded else (3, 8)
    h, w = draw(st.integers(*side)), draw(st.integers(*side))
    cells = h * w
    n_static = draw(st.integers(0, 2 if crowded else cells // 3))
    most = cells - n_static - 1 if crowded else min(6, (cells - n_static) // 2)
    n_robots = draw(st.integers(1, max(1, most)))
    horizon = draw(st.integers(2 if crowded else 1, 14))
    k_max = cells - n_static - n_robots
    dynamic = (crowded or draw(st.booleans())) and k_max > 0 and horizon >= 2
    n_dynamic = draw(st.integers(1, min(k_max, 12))) if dynamic else 0
    add_every = draw(st.integers(1, max(1, (9 * horizon) // 10)))
    cfg = WorldConfig(
        height=h, width=w, n_static=n_static, n_robots=n_robots, dynamic=dynamic,
        n_dynamic=n_dynamic, add_every=add_every, horizon=horizon,
        vision=draw(st.sampled_from([1, 3, 5, 7])),
        explore_mode=draw(st.sampled_from(["visit", "sense"])),
        spawn=draw(st.sampled_from(["random", "corner"])),
        success_elratio=draw(st.sampled_from([0.0, 0.3, 0.6, 0.9])),
        success_max_block_collisions=draw(st.integers(0, 3)),
        r_back=draw(st.sampled_from([-10.0, -1.5])), r_coll=draw(st.sampled_from([-10.0, -3.0])),
        recent_len=draw(st.integers(1, 6)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    episodes = []
    for _ in range(draw(st.integers(1, 3))):
        if draw(st.booleans()):
            key = int(rng.integers(1000)), int(rng.integers(99))
            episodes.append(core.generate_episode(cfg, *key))
        else:
            # arbitrary (maybe split) maps; dynamic cells may sit under a start to test pending
            blocks = np.zeros(cells, dtype=bool)
            blocks[rng.choice(cells, n_static, replace=False)] = True
            free = np.flatnonzero(~blocks)
            starts = rng.choice(free, n_robots, replace=False)
            dyn = rng.choice(free, cfg.n_active_dynamic, replace=False)
            episodes.append((blocks.reshape(h, w), np.stack(np.divmod(starts, w), axis=-1),
                             np.stack(np.divmod(dyn, w), axis=-1)))
    # actions: a per-robot mix of staying (to sit on due blocks and re-visit) and random moves
    p_stay = rng.uniform(0.0, 0.8, size=(len(episodes), n_robots))
    moves = rng.integers(0, 9, size=(horizon, len(episodes), n_robots))
    stay = rng.random((horizon, len(episodes), n_robots)) < p_stay
    return cfg, episodes, np.where(stay, 0, moves)


def check_against_reference(cfg: WorldConfig, episodes: list[Episode],
                             actions: np.ndarray) -> None:
    """Run B episodes batched and through RefWorld; every step must agree exactly."""
    blocks = np.stack([e[0] for e in episodes])
    starts = np.stack([e[1] for e in episodes])
    dyn = np.stack([e[2] for e in episodes])
    state = core.from_layout(cfg, blocks, starts, dyn)
    refs = [ref_of(cfg, *e) for e in episodes]
    assert state.dyn_due.tolist() == due_steps(cfg)
    for b, ref in enumerate(refs):
        assert_matches(cfg, state, b, ref)
    for t in range(cfg.horizon):
        rewards = core.step(cfg, state, actions[t])
        assert rewards.dtype == np.float32
        for b, ref in enumerate(refs):
            assert rewards[b].tolist() == ref.step(actions[t, b].tolist())
            assert_matches(cfg, state, b, ref)
            np.testing.assert_array_equal(state.last_reward[b], rewards[b])
    assert state.done
    m = core.metrics(cfg, state)
    for b, ref in enumerate(refs):
        assert m.block_collisions[b] == sum(ref.block_coll)
        assert m.robot_collisions[b] == sum(ref.robot_coll)
        assert m.collisions[b] == sum(ref.block_coll) + sum(ref.robot_coll)
        assert m.elratio[b] == ref.elratios[-1]
    with pytest.raises(RuntimeError):
        core.step(cfg, state, actions[0])


@settings(max_examples=50, deadline=None, suppress_health_check=SLOW)
@given(scenario=scenarios())
def test_vectorized_step_matches_reference(scenario: Scenario) -> None:
    """Positions, rewards, collisions, explored set, blocks, patches and success match exactly."""
    check_against_reference(*scenario)


@settings(max_examples=30, deadline=None, suppress_health_check=SLOW)
@given(scenario=scenarios(crowded=True))
def test_vectorized_step_matches_reference_in_crowds(scenario: Scenario) -> None:
    check_against_reference(*scenario)


@pytest.mark.parametrize("mode", ["visit", "sense"])
def test_vectorized_step_matches_reference_on_the_paper_world(mode: str) -> None:
    """20 x 20, 81 static + 70 dynamic blocks, 10 robots, T = 30, v = 5: three episodes."""
    cfg = WorldConfig(explore_mode=mode, success_elratio=0.5 if mode == "visit" else 0.9)
    episodes = [core.generate_episode(cfg, 2019, ep) for ep in range(3)]
    rng = np.random.default_rng(294)
    actions = np.where(rng.random((cfg.horizon, 3, 10)) < 0.3, 0,
                       rng.integers(0, 9, size=(cfg.horizon, 3, 10)))
    check_against_reference(cfg, episodes, actions)


def random_episode(cfg: WorldConfig, seed: int, episodes: list[int], action_seed: int,
                   p_stay: float = 0.3) -> Iterator[tuple[core.WorldState, np.ndarray, np.ndarray]]:
    """Run generated episodes with random actions; yield (state, actions, positions before)."""
    state = core.reset(cfg, seed, episodes)
    rng = np.random.default_rng(action_seed)
    for _ in range(cfg.horizon):
        a = np.where(rng.random(state.pos.shape) < p_stay, 0, rng.integers(0, 9, state.pos.shape))
        before = state.pos.copy()
        core.step(cfg, state, a)
        yield state, a, before


@st.composite
def small_worlds(draw: st.DrawFn) -> WorldConfig:
    """Valid small configs: every block count fits and at least one batch precedes 0.9 T."""
    h, w = draw(st.integers(4, 10)), draw(st.integers(4, 10))
    n_static = draw(st.integers(0, h * w // 4))
    n_robots = draw(st.integers(1, 6))
    horizon = draw(st.integers(2, 20))
    return WorldConfig(
        height=h, width=w, n_static=n_static, n_robots=n_robots, horizon=horizon,
        n_dynamic=draw(st.integers(0, min(15, h * w - n_static - n_robots))),
        add_every=draw(st.integers(1, max(1, (9 * horizon) // 10))),
        vision=draw(st.sampled_from([1, 3, 5])),
        explore_mode=draw(st.sampled_from(["visit", "sense"])),
        spawn=draw(st.sampled_from(["random", "corner"])))


small_world = small_worlds()
worlds = small_world | st.sampled_from([WorldConfig(), WorldConfig(explore_mode="sense"),
                                        WorldConfig(add_every=1), WorldConfig(dynamic=False)])


@settings(max_examples=40, deadline=None, suppress_health_check=SLOW)
@given(cfg=worlds, seed=st.integers(0, SEED_MAX), action_seed=st.integers(0, SEED_MAX),
       p_stay=st.floats(0.0, 0.9))
def test_robots_never_on_blocks_and_elratio_never_decreases(
        cfg: WorldConfig, seed: int, action_seed: int, p_stay: float) -> None:
    lay = core.Layout.of(cfg)
    offs = (np.arange(2) * lay.size)[:, None]
    last = (0, 0)  # cumulative block and robot collisions before the step
    for state, a, before in random_episode(cfg, seed, [0, 1], action_seed, p_stay):
        under = state.grid.reshape(-1)[state.pos + offs]
        assert (under == core.FREE).all(), "a robot stands on a block or off the grid"
        yx = lay.to_yx(state.pos)
        assert ((yx >= 0) & (yx < [cfg.height, cfg.width])).all()
        curve = state.elratio[:, :state.t + 1]
        assert (np.diff(curve, axis=1) >= 0).all()
        assert ((curve > 0) & (curve <= 1)).all()
        # a refused non-stay move is exactly one block collision; a robot sharing its cell, one
        refused = (state.pos == before) & (a != STAY)
        np.testing.assert_array_equal(state.block_coll - last[0], refused)
        shared = (state.pos[:, :, None] == state.pos[:, None, :]).sum(-1) > 1
        np.testing.assert_array_equal(state.robot_coll - last[1], shared)
        last = (state.block_coll.copy(), state.robot_coll.copy())


@settings(max_examples=30, deadline=None, suppress_health_check=SLOW)
@given(cfg=worlds, seed=st.integers(0, SEED_MAX), action_seed=st.integers(0, SEED_MAX),
       p_stay=st.sampled_from([0.0, 0.5, 0.95]))
def test_dynamic_block_schedule(cfg: WorldConfig, seed: int, action_seed: int,
                                p_stay: float) -> None:
    """Due times, all due by 0.9 T, and a due block activates at the first step its cell is free."""
    k = cfg.n_active_dynamic
    due = core.dynamic_due(cfg)
    if k:
        batches = (9 * cfg.horizon) // (10 * cfg.add_every)
        n = math.ceil(k / batches)
        assert cfg.batch_size == n
        assert due.tolist() == [(i // n + 1) * cfg.add_every for i in range(k)]
        assert 10 * due.max() <= 9 * cfg.horizon
        assert np.bincount(due // cfg.add_every).max() <= n  # batches of at most n blocks
    free_since_due = np.zeros((2, k), dtype=bool)  # cell was free at some step >= due
    for state, _, _ in random_episode(cfg, seed, [0, 1], action_seed, p_stay):
        occupied = (state.dyn_cells[:, :, None] == state.pos[:, None, :]).any(-1)
        is_due = due <= state.t
        free_since_due |= is_due & ~occupied
        np.testing.assert_array_equal(state.dyn_active, free_since_due)
        active_cells = state.dyn_cells[state.dyn_active]
        grid = state.grid.reshape(-1)
        offs = np.nonzero(state.dyn_active)[0] * state.grid.shape[1]
        assert (grid[active_cells + offs] == core.DYNAMIC).all()
        assert (state.grid == core.DYNAMIC).sum() == state.dyn_active.sum()
    # at the end every block is active except those occupied at every step since it was due
    assert state.done and (due <= cfg.horizon).all()
    assert state.dyn_active.sum() == 2 * k - (~free_since_due).sum()


def test_schedule_formula_over_all_small_configs() -> None:
    """n = ceil(K / floor(0.9 T / m)); full batches every m steps from step m; all due by 0.9 T."""
    checked = 0
    for horizon in range(2, 41):
        for add_every in range(1, (9 * horizon) // 10 + 1):
            batches = (9 * horizon) // (10 * add_every)
            for k in range(1, 73):
                cfg = WorldConfig(n_static=0, n_robots=1, n_dynamic=k, horizon=horizon,
                                  add_every=add_every)
                n = -(-k // batches)
                assert cfg.batch_size == n, (k, horizon, add_every)
                due = core.dynamic_due(cfg)
                assert 10 * int(due[-1]) <= 9 * horizon
                steps, counts = np.unique(due, return_counts=True)
                assert steps.tolist() == [add_every * (i + 1) for i in range(len(steps))]
                assert (counts[:-1] == n).all() and 1 <= counts[-1] <= n
                checked += 1
    assert checked > 20_000
    assert core.dynamic_due(WorldConfig(dynamic=False)).size == 0
    assert WorldConfig().batch_size == 8  # the paper's 70 blocks, T = 30, m = 3


def test_pending_block_waits_for_its_cell_without_holding_up_the_batch() -> None:
    """Two blocks due at step 1: the one under a robot waits; it appears once the robot leaves."""
    cfg = WorldConfig(height=5, width=5, n_static=0, n_robots=1, n_dynamic=3, add_every=2,
                      horizon=5)
    dyn = [[[2, 2], [0, 0], [4, 4]]]
    state = core.from_layout(cfg, np.zeros((1, 5, 5), bool), [[[2, 2]]], dyn)
    assert cfg.batch_size == 2 and state.dyn_due.tolist() == [2, 2, 4]
    core.step(cfg, state, [[STAY]])
    assert state.dyn_active.tolist() == [[False, False, False]]
    core.step(cfg, state, [[STAY]])
    assert state.dyn_active.tolist() == [[False, True, False]]
    core.step(cfg, state, [[E]])  # leave: the pending block activates at once behind the robot
    assert state.dyn_active.tolist() == [[True, True, False]]
    r = core.step(cfg, state, [[W]])  # and it is now a wall
    assert r[0, 0] == cfg.r_coll + cfg.r_back and state.block_coll[0, 0] == 1
    lay = core.Layout.of(cfg)
    assert lay.to_yx(state.pos[0, 0]).tolist() == [2, 3]


@settings(max_examples=25, deadline=None, suppress_health_check=SLOW)
@given(cfg=worlds, seed=st.integers(0, SEED_MAX), action_seed=st.integers(0, SEED_MAX))
def test_same_seed_and_actions_give_identical_episodes(
        cfg: WorldConfig, seed: int, action_seed: int) -> None:
    runs = []
    for _ in range(2):
        steps = []
        for state, _, _ in random_episode(cfg, seed, [0, 4], action_seed):
            steps.append((state.pos.copy(), state.last_reward.copy(), state.grid.copy(),
                          state.explored.copy()))
        runs.append((steps, core.metrics(cfg, state)))
    (a, ma), (b, mb) = runs
    assert len(a) == len(b) == cfg.horizon
    for x, y in zip(a, b, strict=True):
        for u, v in zip(x, y, strict=True):
            np.testing.assert_array_equal(u, v)
    for name in ("reward", "block_collisions", "robot_collisions", "elratio", "success",
                 "repeat_ratio"):
        np.testing.assert_array_equal(getattr(ma, name), getattr(mb, name))


STATE_FIELDS = ["grid", "pos", "explored", "visited", "recent", "dyn_cells", "dyn_active",
                "last_reward", "reward_sum", "block_coll", "robot_coll", "back_count", "elratio",
                "success"]


@settings(max_examples=25, deadline=None, suppress_health_check=SLOW)
@given(cfg=worlds, seed=st.integers(0, SEED_MAX), action_seed=st.integers(0, SEED_MAX))
def test_episodes_do_not_depend_on_their_batch(cfg: WorldConfig, seed: int,
                                               action_seed: int) -> None:
    """reset(cfg, seed, [3, 7]) runs episodes 3 and 7 exactly as two separate resets do."""
    both = core.reset(cfg, seed, [3, 7])
    alone = [core.reset(cfg, seed, [3]), core.reset(cfg, seed, [7])]
    rng = np.random.default_rng(action_seed)
    for _ in range(cfg.horizon):
        a = rng.integers(0, 9, size=(2, cfg.n_robots))
        r = core.step(cfg, both, a)
        for b, single in enumerate(alone):
            np.testing.assert_array_equal(core.step(cfg, single, a[b:b + 1])[0], r[b])
    for b, single in enumerate(alone):
        assert single.episodes.tolist() == [both.episodes[b]]
        for name in STATE_FIELDS:
            np.testing.assert_array_equal(getattr(single, name)[0], getattr(both, name)[b], name)
        mb, ms = core.metrics(cfg, both), core.metrics(cfg, single)
        for name in ("reward", "collisions", "elratio", "success", "repeat_ratio"):
            assert getattr(ms, name)[0] == getattr(mb, name)[b]


# ---------------------------------------------------------------- hand-built maps, reward cases

def tiny(n_robots: int, starts: list[Cell], blocks: list[Cell] = (), dyn: list[Cell] = (),
         **kw) -> tuple[WorldConfig, core.WorldState]:
    """A 5 x 5 world (unless overridden) with given robots, static and dynamic blocks."""
    opts = {"height": 5, "width": 5, "n_static": len(blocks), "n_robots": n_robots,
            "dynamic": bool(dyn), "n_dynamic": len(dyn), "horizon": 10, "add_every": 1}
    opts.update(kw)
    cfg = WorldConfig(**opts)
    grid = np.zeros((1, cfg.height, cfg.width), dtype=bool)
    for y, x in blocks:
        grid[0, y, x] = True
    return cfg, core.from_layout(cfg, grid, [starts], np.array([list(dyn)]).reshape(1, -1, 2))


def where(cfg: WorldConfig, state: core.WorldState) -> list[Cell]:
    return [tuple(c) for c in core.Layout.of(cfg).to_yx(state.pos[0]).tolist()]


def test_standing_still_on_an_explored_cell_pays_r_back() -> None:
    cfg, state = tiny(1, [(2, 2)])
    r = core.step(cfg, state, [[STAY]])
    assert r.tolist() == [[cfg.r_back]]
    assert state.block_coll.sum() == state.robot_coll.sum() == 0 and state.back_count[0, 0] == 1


def test_moving_to_a_fresh_cell_is_free_and_onto_a_teammates_cell_pays_r_back() -> None:
    cfg, state = tiny(2, [(0, 0), (0, 2)])
    assert core.step(cfg, state, [[E, S]]).tolist() == [[0.0, 0.0]]
    # robot 0 steps onto robot 1's start, explored by robot 1 earlier
    assert core.step(cfg, state, [[E, S]]).tolist() == [[cfg.r_back, 0.0]]
    assert where(cfg, state) == [(0, 2), (2, 2)]


def test_two_robots_arriving_together_on_a_fresh_cell_pay_collision_not_r_back() -> None:
    cfg, state = tiny(2, [(2, 1), (2, 3)])
    r = core.step(cfg, state, [[E, W]])
    assert r.tolist() == [[cfg.r_coll, cfg.r_coll]]
    assert state.robot_coll.tolist() == [[1, 1]] and state.block_coll.sum() == 0
    assert where(cfg, state) == [(2, 2), (2, 2)]
    r = core.step(cfg, state, [[STAY, STAY]])  # still together, now on an explored cell
    assert r.tolist() == [[cfg.r_back + cfg.r_coll] * 2]
    assert state.robot_coll.tolist() == [[2, 2]]


def test_three_robots_on_one_cell_each_count_one_robot_collision() -> None:
    cfg, state = tiny(3, [(1, 2), (2, 1), (2, 3)])
    r = core.step(cfg, state, [[S, E, W]])
    assert r.tolist() == [[cfg.r_coll] * 3]
    assert state.robot_coll.tolist() == [[1, 1, 1]]
    # swapping places is not a collision: robots only collide by sharing a cell after the move
    cfg, state = tiny(2, [(2, 1), (2, 2)])
    assert core.step(cfg, state, [[E, W]]).tolist() == [[cfg.r_back, cfg.r_back]]
    assert state.robot_coll.sum() == 0


def test_moving_off_grid_or_into_a_block_is_one_block_collision_and_no_move() -> None:
    cfg, state = tiny(2, [(0, 0), (2, 2)], blocks=[(2, 3)])
    r = core.step(cfg, state, [[N, E]])
    # refused robots stay on their (explored) cell: one block collision each, plus r_back
    assert r.tolist() == [[cfg.r_coll + cfg.r_back] * 2]
    assert where(cfg, state) == [(0, 0), (2, 2)]
    assert state.block_coll.tolist() == [[1, 1]] and state.robot_coll.sum() == 0
    for action in (NW, W, SW):  # every off-grid direction from the corner counts
        core.step(cfg, state, [[action, STAY]])
    assert state.block_coll.tolist() == [[4, 1]]


def test_diagonal_moves_pass_between_two_blocks() -> None:
    """Moves are 8-connected without a corner rule, as the map's connectivity assumes."""
    cfg, state = tiny(1, [(2, 2)], blocks=[(1, 2), (2, 3)])
    assert core.step(cfg, state, [[NE]]).tolist() == [[0.0]]
    assert where(cfg, state) == [(1, 3)]


def test_active_dynamic_block_refuses_moves() -> None:
    cfg, state = tiny(1, [(2, 2)], dyn=[(2, 3)])
    core.step(cfg, state, [[STAY]])  # due at step 1
    assert state.dyn_active.tolist() == [[True]]
    r = core.step(cfg, state, [[E]])
    assert r.tolist() == [[cfg.r_coll + cfg.r_back]] and where(cfg, state) == [(2, 2)]


def test_final_step_pays_r_succ_or_r_fail_to_every_robot() -> None:
    kw = {"height": 3, "width": 3, "horizon": 2, "success_elratio": 4 / 9}
    cfg, state = tiny(2, [(0, 0), (2, 2)], **kw)
    assert core.step(cfg, state, [[E, W]]).tolist() == [[0.0, 0.0]]
    r = core.step(cfg, state, [[STAY, STAY]])  # 4 of 9 cells explored: success, but both stayed
    assert state.elratio[0, -1] == 4 / 9 and state.success.tolist() == [True]
    assert r.tolist() == [[cfg.r_back + cfg.r_succ] * 2]
    cfg, state = tiny(2, [(0, 0), (2, 2)], **kw)
    core.step(cfg, state, [[E, W]])
    r = core.step(cfg, state, [[E, STAY]])  # robot 0 reaches a fresh cell, robot 1 stays
    assert state.elratio[0, -1] == 5 / 9 and state.success.tolist() == [True]
    assert r.tolist() == [[cfg.r_succ, cfg.r_back + cfg.r_succ]]
    cfg, state = tiny(2, [(0, 0), (2, 2)], **{**kw, "success_elratio": 0.9})
    core.step(cfg, state, [[E, W]])
    r = core.step(cfg, state, [[S, NW]])  # two fresh cells, but 6/9 < 0.9
    assert state.success.tolist() == [False]
    assert r.tolist() == [[cfg.r_fail, cfg.r_fail]]
    assert core.metrics(cfg, state).reward.tolist() == [cfg.r_fail]


def test_success_needs_elratio_and_few_enough_team_block_collisions() -> None:
    kw = {"height": 3, "width": 3, "horizon": 2, "success_elratio": 4 / 9}
    for allowed, succeeds in ((0, False), (1, True)):
        cfg, state = tiny(2, [(0, 0), (2, 2)], success_max_block_collisions=allowed, **kw)
        core.step(cfg, state, [[N, W]])  # robot 0 bumps the edge: one team block collision
        r = core.step(cfg, state, [[E, N]])
        assert state.elratio[0, -1] >= cfg.success_elratio
        assert state.success.tolist() == [succeeds]
        bonus = cfg.r_succ if succeeds else cfg.r_fail
        assert r.tolist() == [[bonus, bonus]]  # robot 1 shares the team's outcome
        assert core.metrics(cfg, state).success.tolist() == [succeeds]


def test_sense_mode_pays_r_back_when_a_move_reveals_nothing_new() -> None:
    cfg, state = tiny(2, [(2, 1), (2, 3)], vision=3, explore_mode="sense")
    explored0 = core.Layout.of(cfg).inner(state.explored[0])
    assert explored0[1:4, 0:5].all() and not explored0[0].any() and not explored0[4].any()
    r = core.step(cfg, state, [[STAY, E]])
    assert r.tolist() == [[cfg.r_back, cfg.r_back]]  # staying, and moving inside the seen band
    r = core.step(cfg, state, [[N, N]])  # both reveal parts of row 0, judged before the step
    assert r.tolist() == [[0.0, 0.0]]
    r = core.step(cfg, state, [[E, W]])  # to (1, 2) and (1, 3): all they see is explored
    assert r.tolist() == [[cfg.r_back, cfg.r_back]]
    r = core.step(cfg, state, [[STAY, W]])  # meeting adds a robot collision
    assert r.tolist() == [[cfg.r_back + cfg.r_coll] * 2]


def test_elratio_counts_final_blocks_on_unexplored_cells() -> None:
    cfg, state = tiny(1, [(0, 0)], blocks=[(4, 4)], dyn=[(4, 0), (0, 4)], horizon=3)
    assert state.dyn_due.tolist() == [1, 2]
    assert state.elratio[0, 0] == 2 / 25  # the start cell and the static block
    core.step(cfg, state, [[STAY]])
    core.step(cfg, state, [[STAY]])
    assert state.elratio[0].tolist() == [2 / 25, 3 / 25, 4 / 25, 0.0]


# ---------------------------------------------------------------- decentralized view

positions = st.integers(1, 8).flatmap(lambda n: st.tuples(
    st.lists(st.tuples(st.integers(0, 19), st.integers(0, 19)), min_size=n, max_size=n),
    st.lists(st.booleans(), min_size=n, max_size=n)))


@settings(max_examples=50, deadline=None, suppress_health_check=SLOW)
@given(pp=positions, comm=st.integers(0, 60).map(lambda k: k / 2) | st.just(math.inf))
def test_neighbourhood_is_symmetric_euclidean_and_includes_self(
        pp: tuple[list[Cell], list[bool]], comm: float) -> None:
    pos = np.array([pp[0]], dtype=np.int64)
    present = np.array([pp[1]], dtype=bool)
    hears = neighbourhood(float(comm), pos, present)
    n = pos.shape[1]
    for i in range(n):
        for j in range(n):
            expect = bool(present[0, i] and present[0, j]
                          and math.dist(pp[0][i], pp[0][j]) <= comm)
            assert hears[0, i, j] == expect, (i, j)
    np.testing.assert_array_equal(hears, hears.transpose(0, 2, 1))
    np.testing.assert_array_equal(np.diagonal(hears, axis1=1, axis2=2), present)
    pred = predecessor(hears)
    for i in range(n):
        heard_below = [j for j in range(i) if hears[0, i, j]]
        assert pred[0, i] == (max(heard_below) if heard_below else -1)


def test_comm_range_boundary_is_inclusive_and_inf_hears_everyone() -> None:
    pos = np.array([[[0, 0], [3, 4], [19, 19]]])
    present = np.ones((1, 3), dtype=bool)
    assert neighbourhood(5.0, pos, present)[0, 0].tolist() == [True, True, False]
    assert neighbourhood(4.99, pos, present)[0, 0].tolist() == [True, False, False]
    assert neighbourhood(math.inf, pos, present).all()
    assert predecessor(neighbourhood(5.0, pos, present)).tolist() == [[-1, 0, -1]]


@settings(max_examples=25, deadline=None, suppress_health_check=SLOW)
@given(seed=st.integers(0, SEED_MAX), comm=st.sampled_from([0.0, 2.0, 5.0, math.inf]),
       steps=st.integers(0, 5))
def test_robot_view_of_heard_messages_matches_the_batch_view(seed: int, comm: float,
                                                             steps: int) -> None:
    """What one robot process sees is the batch view restricted to the messages it heard."""
    cfg = WorldConfig(height=8, width=8, n_static=8, n_dynamic=6, n_robots=5, horizon=10,
                      add_every=1, comm_range=comm)
    state = core.reset(cfg, seed, [2, 9])
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        core.step(cfg, state, rng.integers(0, 9, size=(2, cfg.n_robots)))
    view = batch_view(cfg, state)
    n, v = cfg.n_robots, cfg.vision
    assert view.hears.shape == (2, n, n) and view.tick == steps
    for g in range(2):
        for i in range(n):
            heard = heard_by(cfg, view, g, i)
            assert heard.shape == (1, n)
            assert heard.pos.shape == (1, n, 2) and heard.patch.shape == (1, n, v, v)
            assert heard.visited.shape == (1, n, cfg.cells)
            assert heard.recent.shape == (1, n, cfg.recent_len)
            rv = robot_view(cfg, state.seed, int(state.episodes[g]), view.tick, i, heard,
                            float(state.last_reward[g, i]))
            assert rv.hears.shape == (1, n, n) and rv.receivers.tolist() == [
                [j == i for j in range(n)]]
            np.testing.assert_array_equal(rv.hears[0, i], view.hears[g, i])
            assert rv.predecessor()[0, i] == view.predecessor()[g, i]
            assert predecessor_of(rv.hears[0, [i]], np.array([i]))[0] == view.predecessor()[g, i]
            mask = view.hears[g, i]
            assert mask[i]
            np.testing.assert_array_equal(heard.pos[0, mask], view.msgs.pos[g, mask])
            np.testing.assert_array_equal(heard.visited[0, mask], view.msgs.visited[g, mask])
            np.testing.assert_array_equal(heard.patch[0, mask], view.msgs.patch[g, mask])
            assert not heard.visited[0, ~mask].any() and (heard.recent[0, ~mask] == -1).all()
            assert rv.last_reward[0, i] == state.last_reward[g, i]


def test_a_robots_team_memory_equals_its_row_of_the_batch_memory() -> None:
    """TeamMemory of one receiver (a robot process: its own rows only) equals that receiver's row
    of the batched memory (every receiver at once) tick after tick, across an episode start."""
    cfg = WorldConfig(height=10, width=10, n_static=10, n_dynamic=8, n_robots=6, horizon=6,
                      comm_range=3.0)
    batch = TeamMemory(cfg)
    mine = {(g, i): TeamMemory(cfg) for g in range(2) for i in range(cfg.n_robots)}
    rng = np.random.default_rng(5)
    for episode in range(2):
        state = core.reset(cfg, 11, [2 * episode, 2 * episode + 1])
        for _ in range(cfg.horizon):
            view = batch_view(cfg, state)
            full = batch.update(view)
            for (g, i), memory in mine.items():
                rv = robot_view(cfg, view.seed, int(view.episodes[g]), view.tick, i,
                                heard_by(cfg, view, g, i), 0.0)
                row = memory.update(rv)
                np.testing.assert_array_equal(row[0, i], full[g, i])
                assert not np.delete(row[0], i, axis=0).any()  # no other row is ever touched
            core.step(cfg, state, rng.integers(0, 9, size=(2, cfg.n_robots)))


# ---------------------------------------------------------------- counter-based noise

def test_noise_same_key_same_numbers_in_unit_interval() -> None:
    a = uniform(7, np.arange(4)[:, None], 3, np.arange(5)[None, :], 9)
    b = uniform(7, np.arange(4)[:, None], 3, np.arange(5)[None, :], 9)
    assert a.shape == (4, 5, 9)
    np.testing.assert_array_equal(a, b)
    assert ((a >= 0) & (a < 1)).all()
    # one robot process drawing its own key gets the batch's numbers
    np.testing.assert_array_equal(uniform(7, 2, 3, 4, 9), a[2, 4])


def _hash64_reference(*words: object) -> np.ndarray:
    """hash64 as first written: every word through numpy uint64 (the definition of the key)."""
    m1, m2, golden = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB), \
        np.uint64(0x9E3779B97F4A7C15)
    with np.errstate(over="ignore"):
        h = np.uint64(0x243F6A8885A308D3)
        for w in words:
            z = h + golden + np.asarray(w).astype(np.int64).astype(np.uint64)
            z = (z ^ (z >> np.uint64(30))) * m1
            z = (z ^ (z >> np.uint64(27))) * m2
            h = z ^ (z >> np.uint64(31))
        return np.asarray(h, dtype=np.uint64)


def test_noise_scalar_shortcuts_draw_the_reference_numbers() -> None:
    """Folding scalar key words in Python integers, and one robot's key as scalars, give the
    very numbers of the all-numpy definition (negative, large and numpy-scalar words too)."""
    from world.noise import hash64

    rng = np.random.default_rng(0)
    for _ in range(200):
        seed, stream = int(rng.integers(-2**62, 2**62)), int(rng.integers(0, 10))
        ep, tk, rb = (int(v) for v in rng.integers(-5, 2**40, size=3))
        k = np.arange(9)
        want = _hash64_reference(seed, stream, ep, tk, rb, k)
        for key in [(seed, stream, ep, tk, rb, k), (seed, stream, ep, tk, rb, k[None, :]),
                    (np.int64(seed), stream, np.array(ep), tk, rb, k)]:
            np.testing.assert_array_equal(hash64(*key).reshape(-1), want)
        assert hash64(seed, stream, ep) == _hash64_reference(seed, stream, ep)
        for e, t, r in [(ep, tk, rb), (np.array([ep]), tk, np.array([[rb]])),
                        (np.array([ep, ep + 1]), tk, rb)]:
            got = uniform(seed, e, t, r, 9, stream)
            ref = _hash64_reference(seed, stream, np.asarray(e)[..., None],
                                    np.asarray(t)[..., None], np.asarray(r)[..., None], k)
            np.testing.assert_array_equal(
                got, (ref >> np.uint64(11)).astype(np.float64) / 9007199254740992.0)


def test_noise_different_keys_differ() -> None:
    base = uniform(1, 2, 3, 4, 16)
    for other in (uniform(0, 2, 3, 4, 16), uniform(1, 0, 3, 4, 16), uniform(1, 2, 0, 4, 16),
                  uniform(1, 2, 3, 0, 16), uniform(1, 2, 3, 4, 16, stream=1)):
        assert not np.array_equal(base, other)
    assert len(np.unique(base)) == 16


def test_noise_is_roughly_uniform() -> None:
    x = uniform(3, np.arange(100)[:, None], np.arange(100)[None, :], 0, 10).ravel()
    assert x.size == 100_000
    assert abs(x.mean() - 0.5) < 0.01
    counts = np.bincount((x * 20).astype(int), minlength=20)
    chi2 = ((counts - x.size / 20) ** 2 / (x.size / 20)).sum()
    assert chi2 < 60  # 19 degrees of freedom: p < 1e-5 above ~50
    lag = np.corrcoef(x[:-1], x[1:])[0, 1]
    assert abs(lag) < 0.02


@pytest.mark.parametrize("bad", [{"r_back": math.nan}, {"r_succ": math.inf}, {"r_coll": 1e9},
                                 {"success_elratio": 2.0}, {"success_elratio": -0.1},
                                 {"height": 2}, {"vision": 4}])
def test_a_world_config_out_of_range_is_one_line(bad: dict[str, float]) -> None:
    """A reward of nan made every figure nan, a success threshold of 2 every episode a failure:
    refused when the config is made, as the grid and vision already were."""
    from world.config import ConfigError

    with pytest.raises(ConfigError, match=f"world config: {next(iter(bad))}|grid|vision") as e:
        WorldConfig(**bad)  # type: ignore[arg-type]
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("changes", [
    {"dynamic": "false"}, {"height": 20.5}, {"n_robots": 2.5}, {"height": "20"},
    {"comm_range": None}, {"r_back": "x"}, {"n_robots": True}, {"success_max_block_collisions": -1},
    {"recent_len": 10**9}, {"height": 10**5, "width": 10**5}, {"horizon": 10**12},
    {"vision": 2003}, {"height": np.float64(20.5)}, {"comm_range": 1e300},
    {"comm_range": 1e6 + 1}, {"comm_range": -np.inf}, {"add_every": 10**400},
    {"success_max_block_collisions": 10**10}])
def test_a_world_config_built_in_code_checks_its_types_and_ranges(changes: dict) -> None:
    """UA pass: only from_dict checked types, so WorldConfig(dynamic="false") ran every dynamic
    block and WorldConfig(height=20.5) failed deep in numpy."""
    with pytest.raises(ConfigError, match="^world config: "):
        WorldConfig(**changes)


def test_comm_range_is_a_bounded_number_or_unlimited() -> None:
    """UA pass: a finite comm range over ~1.3e154 squared to inf and crashed the radio with an
    OverflowError; finite ranges stop at 1e6 (far past any map's diagonal), inf stays allowed."""
    assert WorldConfig(comm_range=1e6).comm_range == 1e6
    assert WorldConfig(comm_range=np.inf).comm_range == np.inf
    with pytest.raises(ConfigError, match=r"comm_range must lie in \[0, 1000000\] or be inf"):
        WorldConfig(comm_range=1e300)


def test_reset_and_step_refuse_what_is_no_seed_episode_or_move() -> None:
    cfg = WorldConfig(height=6, width=6, n_static=4, n_dynamic=2, n_robots=2, horizon=6)
    for seed, eps in ((1.5, [0]), (2**40, [0]), (-1, [0]), (0, [1.5]), (0, [-1]), (0, []),
                      (0, [True])):
        with pytest.raises(ConfigError):
            core.reset(cfg, seed, eps)  # type: ignore[arg-type]
    state = core.reset(cfg, 0, [0])
    for actions in (np.full((1, 2), np.nan), np.ones((1, 2), bool), np.ones((1, 2))):
        with pytest.raises(ValueError, match="actions must be integers in 0..8"):
            core.step(cfg, state, actions)


def test_numpy_scalars_are_taken_as_the_numbers_they_are() -> None:
    cfg = WorldConfig(height=np.int64(8), width=np.int32(8), n_static=4, n_dynamic=2, n_robots=2,
                      horizon=6, r_back=np.float32(-10))
    assert type(cfg.height) is int and type(cfg.r_back) is float  # (JSON and msgpack take them)
    assert core.reset(cfg, np.int64(3), np.arange(2)).pos.shape == (2, 2)


def test_a_config_file_bool_is_no_number() -> None:
    """`[world] comm_range = true` ran with range 1.0 and `[run] pace = true` at 1 tick/s (UA
    pass): float fields of a config file refuse a bool, as int fields did."""
    from swarm.procs.runconfig import RunConfig
    from world.config import from_dict

    for cls, table in ((WorldConfig, {"comm_range": True}), (RunConfig, {"pace": True}),
                       (RunConfig, {"tick_timeout": True}), (RunConfig, {"watchdog": False})):
        key = next(iter(table))
        with pytest.raises(ConfigError, match=f"{key} must be float, got (True|False)"):
            from_dict(cls, table, "[x]")
    assert from_dict(WorldConfig, {"comm_range": 3}).comm_range == 3.0  # (an int is a number)


def test_a_config_file_integer_is_no_float_and_every_count_has_a_bound() -> None:
    """UA pass: `[eval] episodes = 1e300` was taken as a whole number (and ran until killed)
    while `--episodes 1e30` was an invalid int; a 400-digit `--add-every` overflowed a float
    and a 400-digit `--episodes` broke the progress bar. Int fields refuse floats as the flags
    do, and every count names its upper bound."""
    from swarm.cli.batch import EvalConfig
    from swarm.studies.repro import ReproConfig
    from world.config import from_dict

    for cls, table in ((EvalConfig, {"episodes": 1e300}), (WorldConfig, {"horizon": 30.0}),
                       (WorldConfig, {"add_every": np.float32(3)})):
        with pytest.raises(ConfigError, match=f"{next(iter(table))} must be int, got"):
            from_dict(cls, table, "[x]")
    assert from_dict(WorldConfig, {"horizon": np.int64(12)}).horizon == 12
    for cls, key in ((EvalConfig, "episodes"), (EvalConfig, "batch"),
                     (ReproConfig, "table2_episodes")):
        with pytest.raises(ConfigError, match=rf"{key} must be an integer in \[1, 1000000000\]"):
            cls(**{key: 10**9 + 1})
    assert EvalConfig(episodes=10**9).episodes == 10**9


def test_a_config_file_with_a_byte_order_mark_reads(tmp_path) -> None:
    """Some Windows editors start UTF-8 with a byte-order mark; TOML's parser called it an
    invalid statement at line 1. Bytes that are not UTF-8 are named by their offset in the
    file, the mark included."""
    f = tmp_path / "bom.toml"
    f.write_bytes(b"\xef\xbb\xbf[world]\nheight = 30\n")
    assert load_toml(f) == {"world": {"height": 30}}
    f.write_bytes(b"\xef\xbb\xbf[world]\n# caf\xe9\n")
    with pytest.raises(ConfigError, match=r"is not UTF-8 text \(byte 16\)"):
        load_toml(f)
