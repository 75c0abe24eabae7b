"""Frontier baselines: their choices on hand-built maps, beliefs from heard messages only, and
the same decision in the batched evaluator and in a one-robot (process) view."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from policies import BASELINES, make_policy
from policies.belief import BLOCK, FREE, UNKNOWN
from policies.coordinated_frontier import CoordinatedFrontier
from policies.cost_utility import CostUtility, window_sums
from policies.grid_search import distance_fields, pack, steps_toward, unpack
from policies.nearest_frontier import NearestFrontier
from world import core
from world.config import WorldConfig
from world.core import ACTIONS
from world.decentral import batch_view, heard_by, robot_view

FRONTIER = ("nearest-frontier", "coordinated-frontier", "cost-utility")
PLANNERS = (*FRONTIER, "team-beam")  # every decentralized planner that keeps a belief


def small(n_robots: int, **kw: object) -> WorldConfig:
    return WorldConfig(height=7, width=7, n_static=0, dynamic=False, n_robots=n_robots, **kw)


def world(cfg: WorldConfig, starts: list[tuple[int, int]], blocks: list[tuple[int, int]] = (),
          unexplored: list[tuple[int, int]] | None = None) -> core.WorldState:
    """One episode; with `unexplored`, robot 0's trajectory covers every other cell."""
    grid = np.zeros((1, cfg.height, cfg.width), dtype=bool)
    for y, x in blocks:
        grid[0, y, x] = True
    state = core.from_layout(cfg, grid, np.array([starts]), np.zeros((1, 0, 2), dtype=np.int64))
    if unexplored is not None:
        covered = np.ones((cfg.height, cfg.width), dtype=bool)
        for y, x in unexplored:
            covered[y, x] = False
        state.visited[0, 0] = covered.ravel()
    return state


def bfs(passable: np.ndarray, sources: list[tuple[int, int]]) -> np.ndarray:
    """Reference 8-connected BFS distances (-1 unreachable)."""
    h, w = passable.shape
    dist = np.full((h, w), -1)
    queue = deque()
    for s in sources:
        if passable[s]:
            dist[s] = 0
            queue.append(s)
    while queue:
        y, x = queue.popleft()
        for dy, dx in ACTIONS[1:]:
            ny, nx = y + dy, x + dx
            if 0 <= ny < h and 0 <= nx < w and passable[ny, nx] and dist[ny, nx] < 0:
                dist[ny, nx] = dist[y, x] + 1
                queue.append((ny, nx))
    return dist


@pytest.mark.parametrize("shape", [(7, 7), (9, 70), (6, 64), (13, 27)])
def test_grid_search_matches_bfs(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(1)
    h, w = shape
    passable = rng.random((5, h, w)) > 0.3
    targets = rng.random((5, h, w)) > 0.95
    cells = np.stack([rng.integers(0, h, 5), rng.integers(0, w, 5)], axis=1)
    passable[np.arange(5), cells[:, 0], cells[:, 1]] = True
    assert (unpack(pack(passable), w) == passable).all()
    dist, first = steps_toward(pack(passable), pack(targets), cells)
    src = np.zeros_like(passable)
    src[np.arange(5), cells[:, 0], cells[:, 1]] = True
    fields = distance_fields(pack(passable), pack(src), w)
    for r in range(5):
        to_target = bfs(passable[r], list(zip(*np.nonzero(targets[r]), strict=True)))
        y, x = cells[r]
        assert dist[r] == to_target[y, x]
        for a, (dy, dx) in enumerate(ACTIONS):
            ny, nx = y + dy, x + dx
            inside = 0 <= ny < h and 0 <= nx < w
            on_path = inside and dist[r] > 0 and to_target[ny, nx] == dist[r] - 1
            assert first[r, a] == (on_path or (a == 0 and dist[r] == 0))
        ref = bfs(passable[r], [(y, x)])
        assert (fields[r] == np.where(ref < 0, 255, ref)).all()
        # one search alone (a robot process) takes the single-integer path: the same answer
        one = steps_toward(pack(passable[r:r + 1]), pack(targets[r:r + 1]), cells[r:r + 1])
        assert one[0].tolist() == [dist[r]] and one[1].tolist() == [first[r].tolist()]


def test_one_search_equals_the_batched_search_with_a_step_limit() -> None:
    rng = np.random.default_rng(5)
    for h, w in [(20, 20), (40, 40), (6, 64), (5, 130)]:
        passable = rng.random((40, h, w)) > 0.35
        targets = rng.random((40, h, w)) > 0.97
        cells = np.stack([rng.integers(0, h, 40), rng.integers(0, w, 40)], axis=1)
        passable[np.arange(40), cells[:, 0], cells[:, 1]] = True
        for limit in (None, 3):
            dist, first = steps_toward(pack(passable), pack(targets), cells, limit)
            for r in range(40):
                one = steps_toward(pack(passable[r:r + 1]), pack(targets[r:r + 1]),
                                   cells[r:r + 1], limit)
                assert one[0].tolist() == [dist[r]], (h, w, limit, r)
                assert one[1].tolist() == [first[r].tolist()], (h, w, limit, r)
        assert (dist > 1).any() and (dist < 0).any()


def test_one_distance_field_equals_the_batched_fields() -> None:
    """A robot's one search (a Python integer) gives the batch's row, with every stop rule."""
    rng = np.random.default_rng(6)
    for h, w in [(20, 20), (40, 40), (6, 64), (5, 130)]:
        passable = pack(rng.random((30, h, w)) > 0.35)
        sources = pack(rng.random((30, h, w)) > 0.98)
        targets = pack(rng.random((30, h, w)) > 0.97)
        for kw in ({}, {"max_steps": 16}, {"max_steps": 3}, {"targets": targets, "extra": 4},
                   {"targets": targets, "extra": 0, "max_steps": 9}):
            batch = distance_fields(passable, sources, w, **kw)
            for r in range(30):
                one_kw = {**kw, "targets": targets[r:r + 1]} if "targets" in kw else kw
                one = distance_fields(passable[r:r + 1], sources[r:r + 1], w, **one_kw)
                assert np.array_equal(one, batch[r:r + 1]), (h, w, kw.keys(), r)
            if not kw:  # fields that grow past a step and leave cells unreached
                assert ((batch > 1) & (batch < 255)).any() and (batch == 255).any()


def test_window_sums() -> None:
    mask = np.random.default_rng(2).random((2, 7, 9)) > 0.5
    padded = np.pad(mask, ((0, 0), (2, 2), (2, 2)))
    ref = [[[padded[r, y:y + 5, x:x + 5].sum() for x in range(9)] for y in range(7)]
           for r in range(2)]
    assert (window_sums(mask, 2) == np.array(ref)).all()


def test_nearest_steps_toward_nearest_unexplored() -> None:
    cfg = small(1)
    state = world(cfg, [(3, 3)], unexplored=[(3, 1), (6, 6)])
    action = NearestFrontier(cfg).act(batch_view(cfg, state))[0, 0]
    assert action in (6, 7, 8)  # SW, W, NW: each one step from (3, 1)


def test_nearest_walks_around_a_seen_block() -> None:
    cfg = small(1)
    wall = [(y, 2) for y in range(6)]
    state = world(cfg, [(1, 3)], blocks=wall, unexplored=[(1, 0)])
    pol = NearestFrontier(cfg)
    for _ in range(14):  # 10 steps through the gap at row 6
        core.step(cfg, state, pol.act(batch_view(cfg, state)))
        if state.visited[0, 0, 1 * cfg.width + 0]:
            break
    assert state.visited[0, 0, cfg.width * 1 + 0], "never reached the frontier behind the wall"
    assert state.block_coll.sum() == 0


def test_coordinated_splits_robots_that_nearest_sends_to_one_frontier() -> None:
    cfg = small(2)
    starts, fresh = [(3, 2), (3, 4)], [(3, 3), (3, 0), (3, 6)]
    outcomes = {}
    for cls in (NearestFrontier, CoordinatedFrontier):
        state = world(cfg, starts, unexplored=fresh)
        pol = cls(cfg)
        core.step(cfg, state, pol.act(batch_view(cfg, state)))
        outcomes[cls] = state.robot_coll.sum()
    assert outcomes[NearestFrontier] == 2  # both took the one nearest frontier (3, 3)
    assert outcomes[CoordinatedFrontier] == 0
    state = world(cfg, starts, unexplored=fresh)
    pol = CoordinatedFrontier(cfg)
    view = batch_view(cfg, state)
    targets = pol.assign(view, pol.belief.snapshot(view))
    assert targets[0] != targets[1] and cfg.width * 3 + 3 in targets


def full_search_assignment(pol: CoordinatedFrontier, view, snap) -> np.ndarray:  # noqa: ANN001
    """Burgard et al.'s greedy assignment the plain way: every round scores every (member, cell)
    pair of every receiver anew, [R, N, H*W] at once."""
    cfg = pol.cfg
    r_idx, j_idx = np.nonzero(view.hears[snap.g, snap.i])
    src = np.zeros((len(r_idx), cfg.height, cfg.width), dtype=bool)
    src[np.arange(len(r_idx)), *view.msgs.pos[snap.g[r_idx], j_idx].T] = True
    dist = distance_fields(snap.passable_bits[r_idx], pack(src), cfg.width,
                           targets=snap.targets_bits[r_idx], extra=4)
    d = dist.reshape(len(r_idx), -1)
    cost = np.full((snap.size, view.n, cfg.cells), np.inf, dtype=np.float32)
    ok = (d != 255) & snap.targets.reshape(snap.size, -1)[r_idx]
    cost[r_idx, j_idx] = np.where(ok, d.astype(np.float32), np.inf)
    cols = np.flatnonzero(np.isfinite(cost).any(axis=(0, 1)))
    from world.noise import uniform
    groups, gi = np.unique(snap.g, return_inverse=True)
    noise = uniform(view.seed, view.episodes[groups][:, None], view.tick,
                    np.arange(view.n)[None], cfg.cells, stream=3)[..., cols]
    score = -pol.beta * cost[..., cols] + 1e-4 * noise.astype(np.float32)[gi]
    util = snap.targets.reshape(snap.size, -1)[:, cols].astype(np.float32)
    taken = np.zeros((snap.size, view.n), dtype=bool)
    target = np.full(snap.size, -1, dtype=np.int64)
    for r in range(snap.size):
        while len(cols):
            s = score[r] + util[r][None]
            s[taken[r]] = -np.inf
            j, c = np.unravel_index(s.argmax(), s.shape)
            if not np.isfinite(s[j, c]):
                break
            taken[r, j] = True
            y, x = divmod(int(cols[c]), cfg.width)
            cy, cx = np.divmod(cols, cfg.width)
            near = np.maximum(abs(cy - y), abs(cx - x))
            hit = np.clip(1 - near / (pol.reach + 1), 0, None).astype(np.float32)
            util[r] = np.maximum(util[r] - hit, 0)
            if j == snap.i[r]:
                target[r] = cols[c]
                break
    return target


@pytest.mark.parametrize("size,robots,comm,chunk", [
    ((20, 20), 10, 10.0, 1 << 22), ((20, 20), 10, 4.0, 900), ((40, 40), 30, 10.0, 1 << 22),
    ((13, 27), 12, 6.0, 3000)])
def test_coordinated_assignment_equals_the_full_search(size: tuple[int, int], robots: int,
                                                       comm: float, chunk: int,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The incremental, chunked assignment picks what a full search every round picks, for
    every receiver of several episodes along their first ticks (chunks of a few receivers
    too)."""
    import policies.coordinated_frontier as cf
    monkeypatch.setattr(cf, "CHUNK_FLOATS", chunk)
    h, w = size
    cfg = WorldConfig(height=h, width=w, n_robots=robots, comm_range=comm,
                      n_static=h * w // 5, n_dynamic=h * w // 6, horizon=12)
    pol = CoordinatedFrontier(cfg)
    state = core.reset(cfg, 3, [0, 1, 2])
    checked = assigned = 0
    while not state.done:
        view = batch_view(cfg, state)
        snap = pol.belief.snapshot(view)
        got = pol.assign(view, snap)
        np.testing.assert_array_equal(got, full_search_assignment(pol, view, snap))
        checked += snap.size
        assigned += int((got >= 0).sum())
        actions = np.zeros((3, robots), dtype=np.int64)
        actions[snap.g, snap.i] = pol.pick(view, snap, pol.first_moves(view, snap))
        core.step(cfg, state, actions)
    assert checked == 12 * 3 * robots and assigned > checked // 2


def test_cost_utility_prefers_gain_over_a_slightly_nearer_cell() -> None:
    cfg = small(1)
    fresh = [(3, 1)] + [(0, x) for x in range(7)]  # one cell 2 steps away, a row 3 steps away
    state = world(cfg, [(3, 3)], unexplored=fresh)
    assert NearestFrontier(cfg).act(batch_view(cfg, state))[0, 0] in (6, 7, 8)
    action = CostUtility(cfg, lam=1.0).act(batch_view(cfg, state))[0, 0]
    assert ACTIONS[action, 0] == -1  # up, toward the row


def test_belief_is_built_from_heard_messages_only() -> None:
    cfg = small(3, comm_range=2.5)
    state = world(cfg, [(0, 0), (2, 1), (6, 6)], blocks=[(4, 2), (5, 5)])
    pol = NearestFrontier(cfg)
    view = batch_view(cfg, state)
    assert view.hears[0, 0].tolist() == [True, True, False]
    pol.act(view)
    p = cfg.vision // 2
    known = pol.belief.known[0, :, p:p + 7, p:p + 7]
    assert known[0, 4, 2] == BLOCK  # seen by robot 1, which robot 0 heard
    assert known[0, 5, 5] == UNKNOWN and known[0, 6, 6] == UNKNOWN  # only robot 2 saw these
    assert known[2, 5, 5] == BLOCK and known[2, 0, 0] == UNKNOWN
    team = pol.belief.visited[0].reshape(3, 7, 7)
    assert team[0, 2, 1] and not team[0, 6, 6]
    # A robot process holds only its own row: other rows stay empty.
    own = NearestFrontier(cfg)
    own.act(robot_view(cfg, 0, 0, 0, 1, heard_by(cfg, view, 0, 1), 0.0))
    rows = own.belief.known[0, :, p:p + 7, p:p + 7]
    assert (rows[0] == UNKNOWN).all() and (rows[2] == UNKNOWN).all()
    assert (rows[1] == known[1]).all() and rows[1, 0, 0] == FREE


@pytest.mark.parametrize("name", (*BASELINES, "team-beam"))
def test_robot_view_decides_like_the_batched_view(name: str) -> None:
    cfg = WorldConfig(height=12, width=12, n_static=20, n_dynamic=10, n_robots=5, comm_range=4.0,
                      horizon=12, add_every=2)
    state = core.reset(cfg, seed=3, episodes=[0, 1])
    batched = make_policy(name, cfg)
    batched.reset(2)
    robots = {(g, i): make_policy(name, cfg) for g in range(2) for i in range(cfg.n_robots)}
    for pol in robots.values():
        pol.reset(1)
    while not state.done:
        view = batch_view(cfg, state)
        actions = batched.act(view)
        for (g, i), pol in robots.items():
            own = robot_view(cfg, state.seed, int(state.episodes[g]), state.t, i,
                             heard_by(cfg, view, g, i), float(view.last_reward[g, i]))
            solo = pol.act(own)
            assert solo[0, i] == actions[g, i], f"robot {i} of group {g} at tick {state.t}"
            assert (np.delete(solo[0], i) == 0).all()
        core.step(cfg, state, actions)


@pytest.mark.parametrize("name", PLANNERS)
def test_unheard_robot_does_not_change_a_decision(name: str) -> None:
    cfg = WorldConfig(height=12, width=12, n_static=0, dynamic=False, n_robots=3, comm_range=3.0)
    heard = [(1, 1), (2, 3)]
    a = world(cfg, heard + [(10, 10)])
    b = world(cfg, heard + [(7, 11)])
    for state in (a, b):  # two earlier ticks, the far robot wandering differently
        pol = make_policy(name, cfg)
        for _ in range(2):
            acts = pol.act(batch_view(cfg, state))
            acts[0, 2] = 1 if state is a else 6
            core.step(cfg, state, acts)
        state.policy = pol  # type: ignore[attr-defined]
    assert not (batch_view(cfg, a).hears[0, :2, 2]).any()
    assert (a.pos[0, :2] == b.pos[0, :2]).all() and a.pos[0, 2] != b.pos[0, 2]
    act_a = a.policy.act(batch_view(cfg, a))  # type: ignore[attr-defined]
    act_b = b.policy.act(batch_view(cfg, b))  # type: ignore[attr-defined]
    assert (act_a[0, :2] == act_b[0, :2]).all()
