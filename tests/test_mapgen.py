"""Property tests of the seeded maze generator and of one episode's map, spawn and block draw."""

from __future__ import annotations

import hashlib
from collections import deque

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from world import core
from world.config import ConfigError, WorldConfig
from world.mapgen import RING, SIMPLE, _ring_pattern, generate_static, is_connected

SLOW = [HealthCheck.too_slow]  # a busy 2-core CI box must not fail a test for being slow
NEIGHBOURS8 = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]


def bfs_components(free: np.ndarray) -> int:
    """Number of 8-connected components of the free cells (plain BFS over Python tuples)."""
    h, w = free.shape
    cells = {(y, x) for y in range(h) for x in range(w) if free[y, x]}
    seen: set[tuple[int, int]] = set()
    parts = 0
    for start in sorted(cells):
        if start in seen:
            continue
        parts += 1
        seen.add(start)
        queue = deque([start])
        while queue:
            y, x = queue.popleft()
            for dy, dx in NEIGHBOURS8:
                nxt = (y + dy, x + dx)
                if nxt in cells and nxt not in seen:
                    seen.add(nxt)
                    queue.append(nxt)
    return parts


# Grids and block counts the generator must handle: up to 40% of the cells blocked (the paper's
# map is 20%; past ~45% the greedy generator can wall itself into loops and gives up, see below).
grid_sizes = st.tuples(st.integers(3, 14), st.integers(3, 14))


@settings(max_examples=40, deadline=None, suppress_health_check=SLOW)
@given(size=grid_sizes, frac=st.floats(0.0, 0.4), seed=st.integers(0, 2**32 - 1))
def test_generator_places_exact_blocks_and_keeps_free_space_connected(
        size: tuple[int, int], frac: float, seed: int) -> None:
    h, w = size
    n = int(frac * h * w)
    blocks = generate_static(h, w, n, np.random.default_rng(seed))
    assert blocks.shape == (h, w) and blocks.dtype == bool
    assert int(blocks.sum()) == n
    assert is_connected(~blocks)
    assert bfs_components(~blocks) == 1


def test_impossible_block_counts_fail_loudly() -> None:
    """A request no connected map can meet raises a clear error instead of looping forever."""
    with pytest.raises(ConfigError, match="9 static blocks do not fit on 3 x 3"):
        generate_static(3, 3, 9, np.random.default_rng(0))


def test_a_dense_map_is_finished_cell_by_cell_and_stays_connected() -> None:
    """60 blocks on 10 x 10: random wall segments stop fitting in a third of the episodes (the
    generator raised mid-eval, UA pass); the rest are blocked one cell at a time, each keeping
    the free cells connected, and maps the segments finish are as before."""
    cfg = WorldConfig(height=10, width=10, n_static=60, n_robots=3, dynamic=False)
    for ep in range(30):
        blocks, starts, _ = core.generate_episode(cfg, 0, ep)
        assert int(blocks.sum()) == 60 and is_connected(~blocks)
        assert not blocks[starts[:, 0], starts[:, 1]].any()
    before = core.generate_episode(WorldConfig(), 0, 3)[0]  # a default map: bit for bit as ever
    assert hashlib.sha1(before.tobytes()).hexdigest()[:12] == "22e565be36cb"


def test_default_maps_have_81_blocks_and_one_free_component() -> None:
    cfg = WorldConfig()
    for ep in range(20):
        blocks, _, _ = core.generate_episode(cfg, 0, ep)
        assert int(blocks.sum()) == 81
        assert bfs_components(~blocks) == 1


def test_is_connected_agrees_with_independent_bfs_on_random_maps() -> None:
    """The checker the generator relies on is itself right, on connected and split maps."""
    rng = np.random.default_rng(0)
    verdicts = set()
    for _ in range(300):
        h, w = rng.integers(3, 9, size=2)
        free = rng.random((h, w)) < rng.uniform(0.3, 0.9)
        expect = bfs_components(free) <= 1
        assert is_connected(free) == expect
        verdicts.add(expect)
    assert verdicts == {True, False}


def test_is_connected_uses_8_connectivity() -> None:
    diagonal = np.eye(4, dtype=bool)  # free cells touching only at corners
    assert is_connected(diagonal)
    split = np.ones((5, 5), dtype=bool)
    split[:, 2] = False  # a full wall column
    assert not is_connected(split)
    assert is_connected(np.zeros((3, 3), dtype=bool))


def test_simple_point_table_never_disconnects() -> None:
    """Blocking a cell the table calls simple keeps its free neighbours 8-connected."""
    for pattern in range(256):
        if not SIMPLE[pattern]:
            continue
        free = np.zeros((3, 3), dtype=bool)
        for k, (dy, dx) in enumerate(RING):
            free[1 + dy, 1 + dx] = bool(pattern >> k & 1)
        assert _ring_pattern(free, 1, 1) == pattern
        assert bfs_components(free) == 1  # centre already blocked: the ring alone is connected


def small_config(draw: st.DrawFn) -> WorldConfig:
    h, w = draw(grid_sizes)
    cells = h * w
    n_static = draw(st.integers(0, cells // 3))
    n_robots = draw(st.integers(1, max(1, min(6, (cells - n_static) // 3))))
    room = cells - n_static - n_robots
    dynamic = draw(st.booleans())
    n_dynamic = draw(st.integers(0, min(room, 20))) if dynamic else 0
    horizon = draw(st.integers(4, 20))
    add_every = draw(st.integers(1, max(1, int(0.9 * horizon))))
    return WorldConfig(height=h, width=w, n_static=n_static, n_robots=n_robots, dynamic=dynamic,
                       n_dynamic=n_dynamic, horizon=horizon, add_every=add_every,
                       spawn=draw(st.sampled_from(["random", "corner"])))


small_configs = st.composite(small_config)()


@settings(max_examples=50, deadline=None, suppress_health_check=SLOW)
@given(cfg=small_configs, seed=st.integers(0, 2**31 - 1), ep=st.integers(0, 10_000))
def test_episode_layout_is_valid(cfg: WorldConfig, seed: int, ep: int) -> None:
    blocks, starts, dyn = core.generate_episode(cfg, seed, ep)
    assert int(blocks.sum()) == cfg.n_static
    assert is_connected(~blocks) and bfs_components(~blocks) == 1
    start_set = {tuple(s) for s in starts.tolist()}
    dyn_set = {tuple(d) for d in dyn.tolist()}
    assert starts.shape == (cfg.n_robots, 2) and len(start_set) == cfg.n_robots
    assert dyn.shape == (cfg.n_active_dynamic, 2) and len(dyn_set) == cfg.n_active_dynamic
    for y, x in start_set | dyn_set:
        assert 0 <= y < cfg.height and 0 <= x < cfg.width and not blocks[y, x]
    assert not start_set & dyn_set
    if cfg.spawn == "corner":
        # the starts are the free cells nearest the top-left corner (L1 distance y + x)
        free = {(y, x) for y, x in np.argwhere(~blocks).tolist()}
        worst_start = max(y + x for y, x in start_set)
        best_other = min((y + x for y, x in free - start_set), default=worst_start)
        assert worst_start <= best_other


@settings(max_examples=25, deadline=None, suppress_health_check=SLOW)
@given(cfg=small_configs, seed=st.integers(0, 2**31 - 1), ep=st.integers(0, 10_000))
def test_same_key_same_episode_regardless_of_global_random_state(
        cfg: WorldConfig, seed: int, ep: int) -> None:
    np.random.seed(1)
    first = core.generate_episode(cfg, seed, ep)
    np.random.seed(2)
    np.random.random(17)
    second = core.generate_episode(cfg, seed, ep)
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)


def test_different_keys_give_different_episodes() -> None:
    cfg = WorldConfig()
    keys = [(s, e) for s in range(4) for e in range(4)]
    maps = {core.generate_episode(cfg, s, e)[0].tobytes() for s, e in keys}
    spawns = {core.generate_episode(cfg, s, e)[1].tobytes() for s, e in keys}
    dyns = {core.generate_episode(cfg, s, e)[2].tobytes() for s, e in keys}
    assert len(maps) == len(spawns) == len(dyns) == len(keys)


def test_reset_places_the_generated_episode_on_the_grid() -> None:
    cfg = WorldConfig(n_robots=4, spawn="corner")
    state = core.reset(cfg, 11, [5])
    blocks, starts, dyn = core.generate_episode(cfg, 11, 5)
    lay = core.Layout.of(cfg)
    grid = lay.inner(state.grid)[0]
    np.testing.assert_array_equal(grid == core.STATIC, blocks)
    assert not (grid == core.DYNAMIC).any()  # nothing is due at t = 0
    np.testing.assert_array_equal(lay.to_yx(state.pos[0]), starts)
    np.testing.assert_array_equal(lay.to_yx(state.dyn_cells[0]), dyn)
    assert starts.tolist() == sorted(starts.tolist(), key=lambda c: (c[0] + c[1], c[0], c[1]))
