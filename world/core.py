"""The dynamic exploration world (SPEC section 2) as pure functions over batched numpy arrays.

Every state array has a leading batch axis B (episodes) and, where per robot, an axis N. The grid
is stored *padded* with a border of wall cells (`cfg.pad` wide) and flattened, so a move is an
index addition, leaving the grid is just another block collision and a vision patch is one
gather. Positions are flat indices into the padded grid; `to_yx`/`from_yx` convert.

Order within a step (SPEC): robots move (block collisions), overlaps counted (robot
collisions), B_back judged against the explored set before the step, explored set updated,
pending dynamic blocks activated on unoccupied cells, elratio taken.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from world.config import SEED_MAX, ConfigError, WorldConfig, check_seed
from world.mapgen import generate_static, is_connected

# Cell codes of the padded grid. `code & 3` is what a robot sees: 0 free, 1 block, 2 off-grid.
FREE, STATIC, WALL, DYNAMIC = 0, 1, 2, 9
ROBOT_BIT = 4  # added to a patch cell holding at least one robot

# Action k moves by ACTIONS[k] = (dy, dx): 0 stay, then N, NE, E, SE, S, SW, W, NW.
ACTIONS = np.array([(0, 0), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1)],
                   dtype=np.int64)
N_ACTIONS = 9


@dataclass
class Layout:
    """Index arithmetic of the padded, flattened grid."""

    height: int
    width: int
    pad: int
    vision: int

    @classmethod
    def of(cls, cfg: WorldConfig) -> Layout:
        return cls(cfg.height, cfg.width, cfg.pad, cfg.vision)

    @property
    def hp(self) -> int:
        return self.height + 2 * self.pad

    @property
    def wp(self) -> int:
        return self.width + 2 * self.pad

    @property
    def size(self) -> int:
        return self.hp * self.wp

    @property
    def deltas(self) -> np.ndarray:
        """Flat index change of each action, [9]."""
        return ACTIONS[:, 0] * self.wp + ACTIONS[:, 1]

    @property
    def window(self) -> np.ndarray:
        """Flat offsets of the v x v patch around a cell, row-major, [v*v]."""
        r = self.vision // 2
        dy, dx = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij")
        return (dy * self.wp + dx).ravel()

    def to_yx(self, flat: np.ndarray) -> np.ndarray:
        """Padded flat indices -> grid (y, x), shape [..., 2]."""
        flat = np.asarray(flat)
        return np.stack([flat // self.wp - self.pad, flat % self.wp - self.pad], axis=-1)

    def from_yx(self, yx: np.ndarray) -> np.ndarray:
        yx = np.asarray(yx)
        return (yx[..., 0] + self.pad) * self.wp + yx[..., 1] + self.pad

    def inner(self, padded: np.ndarray) -> np.ndarray:
        """[..., P] padded flat array -> [..., H, W] grid view."""
        g = padded.reshape(*padded.shape[:-1], self.hp, self.wp)
        return g[..., self.pad:self.pad + self.height, self.pad:self.pad + self.width]


@dataclass
class WorldState:
    """Batched state of B episodes; mutated in place by `step`."""

    cfg: WorldConfig  # the config it was reset with; every (cfg, state) function refuses another
    seed: int
    episodes: np.ndarray  # [B] int64 episode numbers (with seed they key maps and noise)
    t: int  # steps done, shared by the batch
    grid: np.ndarray  # [B, P] uint8 cell codes
    pos: np.ndarray  # [B, N] int64 padded flat positions
    alive: np.ndarray  # [B, N] bool; a dead robot neither moves, blocks nor collides
    explored: np.ndarray  # [B, P] bool
    visited: np.ndarray  # [B, N, H*W] bool, each robot's own trajectory bitmap (grid flat index)
    recent: np.ndarray  # [B, N, L] int64 last L grid flat positions y*W+x, oldest first (-1: none)
    dyn_cells: np.ndarray  # [B, K] int64 padded flat cells of the dynamic blocks
    dyn_due: np.ndarray  # [K] int64 step count at which each dynamic block is due
    dyn_active: np.ndarray  # [B, K] bool
    last_reward: np.ndarray  # [B, N] float32
    reward_sum: np.ndarray  # [B, N] float64
    block_coll: np.ndarray  # [B, N] int64 cumulative
    robot_coll: np.ndarray  # [B, N] int64 cumulative
    back_count: np.ndarray  # [B, N] int64 cumulative steps paying r_back
    elratio: np.ndarray  # [B, T+1] float64, index t = after t steps
    success: np.ndarray  # [B] bool, valid once t == T

    @property
    def batch(self) -> int:
        return self.pos.shape[0]

    @property
    def done(self) -> bool:
        return self.t >= self.elratio.shape[1] - 1


def episode_rng(seed: int, episode: int) -> np.random.Generator:
    """The generator of one episode's map, spawn and schedule: same key, same episode, any
    machine."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), int(episode)])))


def dynamic_due(cfg: WorldConfig) -> np.ndarray:
    """Step count at which each dynamic block is due, [K]: batches of n every m steps."""
    k = cfg.n_active_dynamic
    if k == 0:
        return np.zeros(0, dtype=np.int64)
    return (np.arange(k) // cfg.batch_size + 1) * cfg.add_every


def generate_episode(cfg: WorldConfig, seed: int,
                     episode: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One episode's static map [H, W] bool, start cells [N, 2] (y, x) and dynamic cells [K, 2]."""
    rng = episode_rng(seed, episode)
    blocks = generate_static(cfg.height, cfg.width, cfg.n_static, rng)
    assert is_connected(~blocks), "map generator broke connectivity"
    free = np.flatnonzero(~blocks.ravel())
    n = cfg.n_robots
    if cfg.spawn == "corner":
        yy, xx = np.divmod(free, cfg.width)
        order = np.lexsort((xx, yy, yy + xx))
        starts = free[order[:n]]
    else:
        starts = rng.choice(free, size=n, replace=False)
    rest = np.setdiff1d(free, starts)
    dyn = rng.choice(rest, size=cfg.n_active_dynamic, replace=False)
    to_yx = lambda f: np.stack(np.divmod(f, cfg.width), axis=-1)  # noqa: E731
    return blocks, to_yx(starts), to_yx(dyn)


def reset(cfg: WorldConfig, seed: int, episodes: np.ndarray | list[int]) -> WorldState:
    """Start one generated episode per entry of `episodes` (keyed with `seed`)."""
    check_seed(seed)
    seed = int(seed)
    raw = np.asarray(episodes).reshape(-1)
    if raw.size == 0 or raw.dtype.kind not in "iu" or raw.min() < 0 or raw.max() > SEED_MAX:
        raise ConfigError(f"episodes must be one or more integers in [0, {SEED_MAX}], got "
                          f"{np.asarray(episodes).tolist()!r:.80}")
    episodes = raw.astype(np.int64)
    gen = [generate_episode(cfg, seed, int(ep)) for ep in episodes]
    return from_layout(cfg, np.stack([g[0] for g in gen]), np.stack([g[1] for g in gen]),
                       np.stack([g[2] for g in gen]), seed=seed, episodes=episodes)


def _cells(what: str, cells: object, shape: tuple[int, int, int], cfg: WorldConfig) -> np.ndarray:
    """`cells` as an int64 array of `shape` ([B, M, 2] (y, x) grid cells) or a one-line
    ValueError naming the first bad entry."""
    arr = np.asarray(cells)
    if arr.size == 0 and shape[1] == 0:
        return np.zeros(shape, dtype=np.int64)
    if arr.shape != shape:
        raise ValueError(f"{what} must be [B, {shape[1]}, 2] = {list(shape)} (y, x) cells, got "
                         f"shape {list(arr.shape)}")
    if arr.dtype.kind not in "iu":
        raise ValueError(f"{what} must be integer (y, x) cells, got {arr.dtype} "
                         f"{arr.ravel()[:6].tolist()!r:.80}")
    off = (arr[..., 0] < 0) | (arr[..., 0] >= cfg.height) | (arr[..., 1] < 0) | \
        (arr[..., 1] >= cfg.width)
    if off.any():
        g, i = np.argwhere(off)[0]
        raise ValueError(f"{what}[{g}][{i}] = {arr[g, i].tolist()} lies off the {cfg.height} x "
                         f"{cfg.width} grid")
    return arr.astype(np.int64)


def from_layout(cfg: WorldConfig, blocks: np.ndarray, starts: np.ndarray, dynamic: np.ndarray,
                seed: int = 0, episodes: np.ndarray | None = None) -> WorldState:
    """Start episodes on given maps: static blocks [B, H, W] bool, starts [B, N, 2] and dynamic
    block cells [B, K, 2] as (y, x) with K = cfg.n_active_dynamic (hand-built maps in tests).
    Each robot starts on its own free cell; a bad input is a one-line ValueError naming it."""
    lay = Layout.of(cfg)
    check_seed(seed)
    blocks = np.asarray(blocks)
    if blocks.ndim != 3 or blocks.shape[0] < 1 or blocks.shape[1:] != (cfg.height, cfg.width):
        raise ValueError(f"blocks must be [B, {cfg.height}, {cfg.width}] with B >= 1, got shape "
                         f"{list(blocks.shape)}")
    if blocks.dtype != bool and not np.isin(blocks, (0, 1)).all():
        raise ValueError(f"blocks must be bool (or 0/1), got {blocks.dtype} values")
    blocks = blocks.astype(bool)
    b, n, p, k = blocks.shape[0], cfg.n_robots, lay.size, cfg.n_active_dynamic
    starts = _cells("starts", starts, (b, n, 2), cfg)
    dynamic = _cells("dynamic", dynamic, (b, k, 2), cfg)
    for g, i in np.argwhere(blocks[np.arange(b)[:, None], starts[..., 0], starts[..., 1]]):
        raise ValueError(f"starts[{g}][{i}] = {starts[g, i].tolist()} is a block")
    flat = starts[..., 0] * cfg.width + starts[..., 1]
    order = np.argsort(flat, axis=1, kind="stable")
    same = np.argwhere(np.diff(np.take_along_axis(flat, order, 1), axis=1) == 0)
    if len(same):
        g, m = same[0]
        i, j = order[g, m], order[g, m + 1]
        raise ValueError(f"starts[{g}][{i}] and starts[{g}][{j}] are both "
                         f"{starts[g, i].tolist()}: each robot needs its own start cell")
    episodes = np.arange(b) if episodes is None else np.asarray(episodes)
    if episodes.shape != (b,) or episodes.dtype.kind not in "iu":
        raise ValueError(f"episodes must be {b} integers (one per map), got "
                         f"{episodes.tolist()!r:.80}")
    grid = np.full((b, lay.hp, lay.wp), WALL, dtype=np.uint8)
    inner = (slice(None), slice(lay.pad, lay.pad + cfg.height), slice(lay.pad, lay.pad + cfg.width))
    grid[inner] = np.where(blocks, STATIC, FREE)
    grid = grid.reshape(b, p)
    pos = lay.from_yx(starts).astype(np.int64)
    state = WorldState(
        cfg=cfg, seed=int(seed), episodes=episodes.astype(np.int64), t=0, grid=grid, pos=pos,
        alive=np.ones((b, n), dtype=bool),
        explored=np.zeros((b, p), dtype=bool),
        visited=np.zeros((b, n, cfg.cells), dtype=bool),
        recent=np.full((b, n, cfg.recent_len), -1, dtype=np.int64),
        dyn_cells=lay.from_yx(dynamic).astype(np.int64).reshape(b, k), dyn_due=dynamic_due(cfg),
        dyn_active=np.zeros((b, k), dtype=bool),
        last_reward=np.zeros((b, n), dtype=np.float32),
        reward_sum=np.zeros((b, n)), block_coll=np.zeros((b, n), dtype=np.int64),
        robot_coll=np.zeros((b, n), dtype=np.int64), back_count=np.zeros((b, n), dtype=np.int64),
        elratio=np.zeros((b, cfg.horizon + 1)), success=np.zeros(b, dtype=bool),
    )
    _record_positions(state, lay)
    _explore(cfg, state, lay)
    state.elratio[:, 0] = elratio(cfg, state)
    return state


def _record_positions(state: WorldState, lay: Layout) -> None:
    b, n = state.pos.shape
    yx = lay.to_yx(state.pos)
    cell = yx[..., 0] * lay.width + yx[..., 1]
    rows = np.arange(b * n)
    state.visited.reshape(b * n, -1)[rows, cell.ravel()] = True
    state.recent[..., :-1] = state.recent[..., 1:]
    state.recent[..., -1] = cell


def _explore(cfg: WorldConfig, state: WorldState, lay: Layout) -> np.ndarray | None:
    """Mark explored cells; in sense mode return per-robot 'revealed something new' [B, N]."""
    b, p = state.explored.shape
    offs = (np.arange(b) * p)[:, None]
    flat = state.explored.reshape(-1)
    if cfg.explore_mode == "visit":
        flat[(state.pos + offs)[state.alive]] = True
        return None
    cells = state.pos[..., None] + lay.window  # [B, N, v*v]
    idx = cells + offs[..., None]
    in_grid = (state.grid.reshape(-1)[idx] != WALL) & state.alive[..., None]
    revealed = (in_grid & ~flat[idx]).any(-1)
    flat[idx[in_grid]] = True
    return revealed


def check_config(cfg: WorldConfig, state: WorldState) -> None:
    """A one-line ConfigError unless `cfg` is the config `state` was reset with: another size,
    vision or horizon would index the state's arrays wrongly without an error."""
    if cfg is not state.cfg and cfg != state.cfg:
        diff = [f"{f.name} {getattr(cfg, f.name)!r} (state's: {getattr(state.cfg, f.name)!r})"
                for f in fields(cfg) if getattr(cfg, f.name) != getattr(state.cfg, f.name)]
        raise ConfigError(f"world config differs from the one the state was reset with: "
                          f"{', '.join(diff)}; pass that config or reset with this one")


def elratio(cfg: WorldConfig, state: WorldState) -> np.ndarray:
    """|explored U blocks now active| / (H W), [B]."""
    check_config(cfg, state)
    covered = state.explored | (state.grid & 1).astype(bool)
    return covered.sum(axis=1) / cfg.cells


def check_actions(actions: object, shape: tuple[int, int]) -> np.ndarray:
    """`actions` as an array if they are moves of `shape` ([B, N]) - integers in 0..8 - else a
    one-line ValueError. The one rule of what a move is: `step`, the batched evaluator and a
    robot process (which sends its own entry) all check a policy's answer with it, so a policy
    whose answer one of them refuses is refused by all (NaN, 1.5, True or 42 is no move; a
    list of ints is as good as its array)."""
    try:
        arr = np.asarray(actions)
    except (TypeError, ValueError) as exc:  # (a ragged list, say)
        raise ValueError(f"actions must be an array of shape {shape}: {exc}") from None
    if arr.shape != tuple(shape):
        raise ValueError(f"actions must have shape {tuple(shape)}, got {arr.shape}")
    if arr.dtype.kind not in "iu" or arr.min(initial=0) < 0 or arr.max(initial=0) >= N_ACTIONS:
        raise ValueError(f"actions must be integers in 0..8, got {arr.dtype} "
                         f"{arr.ravel()[:8].tolist()!r:.80}")
    return arr


def step(cfg: WorldConfig, state: WorldState, actions: np.ndarray) -> np.ndarray:
    """Advance every episode one step with actions [B, N] in 0..8; returns rewards [B, N]
    float32."""
    check_config(cfg, state)
    if state.done:
        raise RuntimeError("episode already ran its horizon; call reset")
    lay = Layout.of(cfg)
    b, n = state.pos.shape
    p = lay.size
    actions = check_actions(actions, (b, n))
    offs = (np.arange(b) * p)[:, None]
    gflat = state.grid.reshape(-1)
    act = np.where(state.alive, actions, 0)
    target = state.pos + lay.deltas[act]
    hit = gflat[target + offs] != FREE
    state.pos = np.where(hit, state.pos, target)
    block_hit = hit & (act != 0)

    same = state.pos[:, :, None] == state.pos[:, None, :]
    same &= state.alive[:, :, None] & state.alive[:, None, :]
    robot_hit = same.sum(-1) > 1

    if cfg.explore_mode == "visit":
        back = state.explored.reshape(-1)[state.pos + offs] & state.alive
        _explore(cfg, state, lay)
    else:
        back = ~_explore(cfg, state, lay) & state.alive
    _record_positions(state, lay)
    state.t += 1
    _activate_dynamic(state, offs)

    state.elratio[:, state.t] = elratio(cfg, state)
    coll = block_hit.astype(np.int64) + robot_hit
    reward = back * cfg.r_back + coll * cfg.r_coll + 0.0  # (+ 0.0: no -0.0 from 0 * r_back)
    state.block_coll += block_hit
    state.robot_coll += robot_hit
    state.back_count += back
    if state.done:
        team_block = state.block_coll.sum(axis=1)
        state.success = (state.elratio[:, state.t] >= cfg.success_elratio) & (
            team_block <= cfg.success_max_block_collisions)
        reward = reward + np.where(state.success, cfg.r_succ, cfg.r_fail)[:, None]
    reward = np.where(state.alive, reward, 0.0).astype(np.float32)
    state.last_reward = reward
    state.reward_sum += reward
    return reward


def _activate_dynamic(state: WorldState, offs: np.ndarray) -> None:
    """Activate due dynamic blocks on cells no live robot occupies; the rest stay pending."""
    pending = ~state.dyn_active & (state.dyn_due <= state.t)[None, :]
    if not pending.any():
        return
    bi, ki = np.nonzero(pending)
    cells = state.dyn_cells[bi, ki]
    occupied = ((state.pos[bi] == cells[:, None]) & state.alive[bi]).any(-1)
    ok = ~occupied
    state.dyn_active[bi[ok], ki[ok]] = True
    state.grid.reshape(-1)[cells[ok] + offs[bi[ok], 0]] = DYNAMIC


def patches(cfg: WorldConfig, state: WorldState) -> np.ndarray:
    """Each robot's v x v view [B, N, v, v] uint8: 0 free, 1 block, 2 off-grid, +4 robot there."""
    check_config(cfg, state)
    lay = Layout.of(cfg)
    b, n = state.pos.shape
    offs = (np.arange(b) * lay.size)[:, None]
    seen = state.grid & 3
    live = (state.pos + offs)[state.alive]
    seen.reshape(-1)[live] |= ROBOT_BIT
    idx = (state.pos + offs)[..., None] + lay.window
    return seen.reshape(-1)[idx].reshape(b, n, cfg.vision, cfg.vision)


@dataclass
class EpisodeMetrics:
    """Per-episode metrics of a finished batch, arrays [B]."""

    reward: np.ndarray  # mean over robots of the episode return
    block_collisions: np.ndarray
    robot_collisions: np.ndarray
    collisions: np.ndarray
    elratio: np.ndarray  # at the last step
    success: np.ndarray
    repeat_ratio: np.ndarray  # steps paying r_back / robot-steps

    @classmethod
    def concat(cls, parts: list[EpisodeMetrics]) -> EpisodeMetrics:
        """The metrics of several batches, episode order kept."""
        return cls(**{k: np.concatenate([getattr(m, k) for m in parts]) for k in METRIC_NAMES})

    @classmethod
    def from_rows(cls, rows: list[dict[str, float]]) -> EpisodeMetrics:
        """From one `row` per episode (e.g. episodes received over the network)."""
        return cls(**{k: np.array([r[k] for r in rows]) for k in METRIC_NAMES})

    def row(self, g: int) -> dict[str, float]:
        """Episode `g`'s metrics as plain floats (a wire record or a JSON row)."""
        return {k: float(getattr(self, k)[g]) for k in METRIC_NAMES}


METRIC_NAMES: tuple[str, ...] = tuple(f.name for f in fields(EpisodeMetrics))


def metrics(cfg: WorldConfig, state: WorldState) -> EpisodeMetrics:
    """The per-episode metrics of a finished episode batch (`state.done`, all T steps run).
    Mid-episode it reports the steps so far, but `success` is still False: it is judged on the
    last step."""
    check_config(cfg, state)
    n_alive = np.maximum(state.alive.sum(1), 1)
    steps = np.maximum(state.t, 1) * n_alive
    block = state.block_coll.sum(1)
    robot = state.robot_coll.sum(1)
    return EpisodeMetrics(
        reward=state.reward_sum.sum(1) / n_alive,
        block_collisions=block, robot_collisions=robot, collisions=block + robot,
        elratio=state.elratio[:, state.t].copy(), success=state.success.copy(),
        repeat_ratio=state.back_count.sum(1) / steps,
    )
