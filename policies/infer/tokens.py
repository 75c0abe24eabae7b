"""Member tokens of the learned policies in numpy: what receiver i reads about member j of its
neighbourhood. The torch networks read the same arrays (`policies.features.Members.of`), so the
features have one implementation, used by robots, the evaluator and the trainer alike.

A token for (receiver i, member j in S_i) has two parts:

- a *member* part, the same for every receiver, computed once per (group, robot): j's v x v
  patch as three one-hot planes (block, off-grid, robot) and j's absolute position in [0, 1];
- a *pair* part, relative to the receiver: an egocentric `crop x crop` window of j's visited
  bitmap centred on the *receiver's* cell (1 visited, 0 not, -1 off-grid), j's recent positions
  relative to i (dy / H, dx / W, valid flag), j's position relative to i, an is-self flag and
  the tick fraction t / T;
- optionally (`team_pool > 0`) an *own* part per receiver, added to its own token only: the
  team map it can assemble from the messages it heard, i.e. the union U_i of its members'
  visited bitmaps, as an egocentric `crop x crop` window (1 / 0 / -1 as above) and as a coarse
  egocentric map, the fraction of cells not in U_i in each block of a k x k grid of blocks
  centred on the receiver.

Every part has a fixed size whatever the map: positions are fractions of the map, windows are
egocentric, and the coarse map always has k = ceil(39 / team_pool) blocks a side (the number
that covers the paper's 20 x 20 grid from any cell with `team_pool`-cell blocks). On a larger
map the blocks grow (`team_pool` cells on 20 x 20, ceil((2 max(H, W) - 1) / k) beyond), so the
coarse map still covers the grid from any cell and a checkpoint runs on a map of any size.

Only heard pairs exist: `Tokens` lists them receiver by receiver, members in id order (the
canonical pair order), so an unheard robot never enters a computation. Receivers are id-major
(all robot-0 receivers of every group, then robot 1, ...), the order CommAttn's chain decodes in.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from policies.belief import BLOCK, Snapshot
from policies.grid_search import distance_fields
from world.config import ConfigError, WorldConfig
from world.core import N_ACTIONS
from world.decentral import View, heard_union

REFERENCE_SIDE = 20  # the map side the coarse team map's block count is fixed by
MAX_SIZE = 4096  # the largest layer width or window side a model config may ask for
BELIEF_CAP = 16  # path lengths in the belief features are capped here (and scaled by it)
HINT_PLANNERS = ("coordinated-frontier", "team-beam", "chain-plan")  # `ModelConfig.hint_planner`
HINT_BEAM = {"beam": 8, "passes": 1}  # the hint's `team-beam` search by default (hint_beam, ..)


@dataclass
class ModelConfig:
    """The feature settings every learned network shares (each network's config extends it)."""

    crop: int = 9
    """Side of the egocentric window of each member's visited bitmap (see policies.infer.tokens)."""
    team_pool: int = 3
    """Block size of the coarse team map (on a 20 x 20 map; blocks grow with the map, see
    policies.infer.tokens) added to the receiver's own token (0: no team map; checkpoints older
    than this field load with 0)."""
    team_memory: bool = True
    """Build the team map from the receiver's memory of every bitmap heard this episode
    (world.decentral.TeamMemory) instead of this tick's messages only, so a lost message costs
    one teammate's latest steps, not its whole map. Changes no weight shape; no effect without
    the team map; checkpoints older than this field load with it off."""
    belief: bool = False
    """Also give the receiver's own token its belief map (policies.belief.Belief: cells known
    free or block from every patch heard this episode, the map the frontier baselines plan on)
    as two egocentric `crop x crop` windows: known blocks, and the path length through cells
    not known to be blocks to the nearest frontier target (the field nearest frontier descends,
    capped at BELIEF_CAP). Needs the team map and memory; widens the own part (`swarm train
    --init CK --belief true` starts the new inputs' weights at zero)."""
    hint: bool = False
    """Also give the receiver's own token coordinated frontier's suggestion (ours): the moves
    on a shortest path toward the target that planner's assignment gives the receiver on the
    same belief map (policies.coordinated_frontier, 9 bits). Needs the belief; widens the own
    part like it (`swarm train --init CK --hint true`)."""
    hint_planner: str = "coordinated-frontier"
    """Whose suggestion the hint is: "coordinated-frontier" (the moves above) or "team-beam"
    (ours: the one move `team-beam` takes on the same belief, with a light search of beam 8
    and one pass, HINT_BEAM; the same 9 inputs, one-hot). Changes no weight shape (`swarm train
    --init CK --hint-planner team-beam` swaps it); checkpoints older than it load with the first.
    "chain-plan" (ours): the move `chain-plan` takes, its chain run beside CommAttn's (in a
    robot process its plan rides in the hidden-state message after the decoder state)."""
    hint_beam: int = 8
    """Beam width of the "team-beam" hint's search (HINT_BEAM; `team-beam` itself: 24); of a
    "chain-plan" hint, its chain head's beam (inside a chain: at most 16; `chain-plan` itself:
    32)."""
    hint_passes: int = 1
    """Rounds of prioritized planning of the "team-beam" hint (`team-beam` itself: 2); a
    "chain-plan" hint's local-search rounds of a chain head (`chain-plan` itself: 4)."""
    hint_prior: float = 0.0
    """Added to the logit of the hinted move (ours; CommAttn): 0, the hint is an input like any
    other; large, the network follows its planner and departs from it only where its own
    logits prefer another move by more than this. Changes no weight shape (`swarm train --init
    CK --hint-prior 8` sets it; a fresh network takes it in --model); in [0, 64]."""

    def __post_init__(self) -> None:
        """Every size an integer in [1, MAX_SIZE] (`team_pool` may be 0) and every switch a
        bool, whether it came from a checkpoint, a weights message or `swarm train --model`."""
        for f in fields(self):
            v, default = getattr(self, f.name), f.default
            if f.name == "hint_planner":  # (the one name field)
                if v not in HINT_PLANNERS:
                    raise ConfigError(f"model {f.name} must be one of {', '.join(HINT_PLANNERS)}, "
                                      f"got {v!r}")
            elif isinstance(default, bool):
                if not isinstance(v, bool):
                    raise ConfigError(f"model {f.name} must be true or false, got {v!r}")
            elif isinstance(default, int):
                lo = 0 if f.name == "team_pool" else 1
                if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= MAX_SIZE:
                    raise ConfigError(f"model {f.name} must be an integer in [{lo}, {MAX_SIZE}], "
                                      f"got {v!r}")
        prior = getattr(self, "hint_prior", 0.0)
        if isinstance(prior, bool) or not isinstance(prior, int | float) or not 0 <= prior <= 64:
            raise ConfigError(f"model hint_prior must be a number in [0, 64], got {prior!r}")
        self.hint_prior = float(prior)
        for name, hi in (("hint_beam", 64), ("hint_passes", 4)):  # (a robot's time per tick)
            if not 1 <= getattr(self, name, 1) <= hi:
                raise ConfigError(f"model {name} must be an integer in [1, {hi}], "
                                  f"got {getattr(self, name)!r}")
        if getattr(self, "belief", False) and not (self.team_pool and self.team_memory):
            raise ConfigError("model belief needs the team map and its memory (team_pool > 0 "
                              "and team_memory true)")
        if getattr(self, "hint", False) and not getattr(self, "belief", False):
            raise ConfigError("model hint needs the belief (the planner plans on it)")


@dataclass
class Tokens:
    """Heard (receiver, member) pairs of R receivers in G groups of N robot slots (numpy)."""

    member_feats: np.ndarray  # [G*N, Fm] float32 per-member part, row g*N + j
    pair_member: np.ndarray  # [P] int64 row of member_feats of each pair
    pair_feats: np.ndarray  # [P, Fp] float32 receiver-relative part
    lens: np.ndarray  # [R] int64 |S_i| (>= 1: a receiver hears itself)
    start: np.ndarray  # [R] int64 first pair of each receiver (its members follow in id order)
    self_pos: np.ndarray  # [R] int64 slot of the receiver among its own members
    group: np.ndarray  # [R] int64
    robot: np.ndarray  # [R] int64
    n: int  # robot slots N
    own_feats: np.ndarray | None = None  # [R, Fo] float32 per-receiver team map (team_pool > 0)

    @property
    def receivers(self) -> int:
        return len(self.group)

    @property
    def width(self) -> int:
        """Largest neighbourhood M."""
        return int(self.lens.max()) if self.receivers else 1

    @property
    def own_row(self) -> np.ndarray:
        """Pair row of each receiver's own token [R]."""
        return self.start + self.self_pos

    def pad_index(self, fill: int) -> tuple[np.ndarray, np.ndarray]:
        """Pair index [R, M] of each receiver's slots (`fill` past its end) and the mask [R, M]."""
        slots = np.arange(self.width)[None, :]
        mask = slots < self.lens[:, None]
        return np.where(mask, self.start[:, None] + slots, fill), mask

    def padded(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-pair rows [P, D] -> [R, M, D] (zeros past each neighbourhood) and mask [R, M];
        with one receiver (a robot's decision) a view of x."""
        if self.receivers == 1 and len(x) == self.lens[0]:  # its members are the pairs
            return x[None], np.ones((1, len(x)), dtype=bool)
        idx, mask = self.pad_index(x.shape[0])
        return np.concatenate([x, np.zeros((1, x.shape[1]), x.dtype)])[idx], mask

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """Tokens [R, N, F] with slot j = robot j (zero where unheard) and the mask [R, N]."""
        member_ids = self.pair_member % self.n
        receiver = np.repeat(np.arange(self.receivers), self.lens)
        tokens = np.concatenate([self.member_feats[self.pair_member], self.pair_feats], axis=1)
        out = np.zeros((self.receivers, self.n, tokens.shape[1]), dtype=tokens.dtype)
        out[receiver, member_ids] = tokens
        mask = np.zeros((self.receivers, self.n), dtype=bool)
        mask[receiver, member_ids] = True
        return out, mask

    @staticmethod
    def cat(parts: list[Tokens]) -> Tokens:
        """Tokens of several views as one batch (groups renumbered), re-sorted id-major."""
        goff = np.cumsum([0] + [len(p.member_feats) // p.n for p in parts])
        poff = np.cumsum([0] + [len(p.pair_member) for p in parts])
        group = np.concatenate([p.group + o for p, o in zip(parts, goff[:-1], strict=True)])
        robot = np.concatenate([p.robot for p in parts])
        order = np.lexsort((group, robot))
        n = parts[0].n
        return Tokens(
            member_feats=np.concatenate([p.member_feats for p in parts]),
            pair_member=np.concatenate([p.pair_member + int(o) * n
                                        for p, o in zip(parts, goff[:-1], strict=True)]),
            pair_feats=np.concatenate([p.pair_feats for p in parts]),
            lens=np.concatenate([p.lens for p in parts])[order],
            start=np.concatenate([p.start + int(o)
                                  for p, o in zip(parts, poff[:-1], strict=True)])[order],
            self_pos=np.concatenate([p.self_pos for p in parts])[order],
            group=group[order], robot=robot[order], n=n,
            own_feats=(None if parts[0].own_feats is None
                       else np.concatenate([p.own_feats for p in parts])[order]),
        )


def team_blocks(team_pool: int) -> int:
    """Blocks a side of the coarse team map (fixed by the model, not the map)."""
    return -(-(2 * REFERENCE_SIDE - 1) // team_pool)


class CellTable:
    """Flat indices of the A x B block of cells at offsets (dy_a, dx_b) from a cell (y, x) of an
    H x W grid, each clamped to [0, y_max] x [0, x_max], as `y_step * y' + x'`, and (`on_grid`)
    whether the unclamped cell lies on the grid.

    Looked up in one table per cell [H*W, A*B] on maps of up to FULL_CELLS cells (two gathers a
    call instead of ~15 small array operations: a robot featurizes a handful of pairs a tick);
    beyond, composed from per-row and per-column tables (memory linear in H + W)."""

    FULL_CELLS = 1600  # 40 x 40: both of a featurizer's full tables then take 4 MB

    def __init__(self, h: int, w: int, dy: np.ndarray, dx: np.ndarray, y_max: int, x_max: int,
                 y_step: int, on_grid: bool = True) -> None:
        ys, xs = np.arange(h)[:, None] + dy[None, :], np.arange(w)[:, None] + dx[None, :]
        self.rows = (np.clip(ys, 0, y_max) * y_step).astype(np.intp)  # [H, A]
        self.cols = np.clip(xs, 0, x_max).astype(np.intp)  # [W, B]
        self.row_in, self.col_in = (ys >= 0) & (ys < h), (xs >= 0) & (xs < w)
        self.w, self.on_grid = w, on_grid
        self.full: tuple[np.ndarray, np.ndarray | None] | None = None
        if h * w <= self.FULL_CELLS:
            cell = self.rows[:, None, :, None] + self.cols[None, :, None, :]
            inside = self.row_in[:, None, :, None] & self.col_in[None, :, None, :]
            self.full = cell.reshape(h * w, -1), inside.reshape(h * w, -1) if on_grid else None

    def __call__(self, y: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(indices [R, A*B], on the grid [R, A*B] bool, None without `on_grid`) of the blocks
        at cells (y, x)."""
        if self.full is not None:
            at = y * self.w + x
            cell, inside = self.full
            return cell[at], None if inside is None else inside[at]
        r = len(y)
        cell = (self.rows[y][:, :, None] + self.cols[x][:, None, :]).reshape(r, -1)
        if not self.on_grid:
            return cell, None
        return cell, (self.row_in[y][:, :, None] & self.col_in[x][:, None, :]).reshape(r, -1)


def chain_search(hint_beam: int, hint_passes: int) -> dict[str, int]:
    """A `chain-plan` hint's search from the model's two hint fields: beam 8 and one pass (the
    default) is `ChainConfig(1, 8, 0, 8)`, beam 32 and 4 passes `chain-plan`'s own search."""
    return {"head_iters": hint_passes, "head_beam": hint_beam, "iters": 0,
            "beam": min(hint_beam, 16)}


def chain_hint(cfg: WorldConfig, search: dict[str, int]) -> Any:
    """`chain-plan` as a hint planner (model fields `hint_beam`, `hint_passes`)."""
    from policies.chain_plan import ChainConfig, ChainPlan

    return ChainPlan(cfg, ChainConfig(**chain_search(search["beam"], search["passes"])))


class Featurizer:
    """Turns a View into `Tokens` for its receivers; member_dim + pair_dim is the token width."""

    def __init__(self, cfg: WorldConfig, crop: int = 9, team_pool: int = 0,
                 memory: bool = False, belief: bool = False, hint: bool = False,
                 hint_planner: str = HINT_PLANNERS[0],
                 hint_search: dict[str, int] | None = None) -> None:
        if crop < 1 or crop % 2 == 0:
            raise ConfigError(f"crop must be a positive odd number, got {crop}")
        if team_pool < 0:
            raise ConfigError(f"team_pool must be >= 0, got {team_pool}")
        if belief and not (team_pool and memory):
            raise ConfigError("belief features need the team map and its memory (team_pool > 0 "
                              "and team_memory true)")
        if hint and not belief:
            raise ConfigError("hint features need the belief (the planner plans on it)")
        self.belief = belief
        self.hint: Any = None
        if hint:  # (imported here: only a network that reads it pays for the planner)
            if hint_planner == "team-beam":
                from policies.central import CentralConfig
                from policies.team_beam import TeamBeam

                self.hint = TeamBeam(cfg, CentralConfig(**(hint_search or HINT_BEAM)))
            elif hint_planner == "chain-plan":
                self.hint = chain_hint(cfg, hint_search or HINT_BEAM)
            elif hint_planner == "coordinated-frontier":
                from policies.coordinated_frontier import CoordinatedFrontier

                self.hint = CoordinatedFrontier(cfg)
            else:
                raise ConfigError(f"hint planner must be one of {', '.join(HINT_PLANNERS)}, "
                                  f"got {hint_planner!r}")
        self.cfg = cfg
        self.crop = crop
        h, w = cfg.height, cfg.width
        # the crop x crop window on a cell: its flat cells (clamped to the grid), which lie on it
        offsets = np.arange(crop) - crop // 2
        self.window = CellTable(h, w, offsets, offsets, h - 1, w - 1, w)
        self.member_dim = 3 * cfg.vision * cfg.vision + 2
        # a patch code's planes (block, off-grid, robot; see world.core.patches) [3, 256]
        c = np.arange(256)
        self.code_planes = np.stack([(c & 3) == 1, (c & 3) == 2, (c & 4) != 0]).astype(np.float32)
        self.norm = np.array([max(h - 1, 1), max(w - 1, 1)], dtype=np.float32)
        self.pair_dim = crop * crop + 3 * cfg.recent_len + 2 + 1 + 1
        self.team_pool = team_pool
        # the team map from view.team_visited (a TeamMemory), not this tick; nothing to
        # remember without a team map
        self.memory = memory and team_pool > 0
        self.own_dim = 0
        if team_pool:
            # k x k blocks of p x p cells, the corner `team_half` cells up and left of the
            # receiver; p grows past team_pool where the map is larger than the reference
            k = team_blocks(team_pool)
            p = max(team_pool, -(-(2 * max(cfg.height, cfg.width) - 1) // k))
            self.block, self.team_k, self.team_half = p, k, (k * p) // 2
            edges = np.arange(k + 1) * p - self.team_half  # block edges, from the cell
            # a cell's block corners in the (H+1) x (W+1) summed-area table, clamped to it
            self.corners = CellTable(h, w, edges, edges, h, w, w + 1, on_grid=False)
            self.own_dim = crop * crop + k * k + (2 * crop * crop if belief else 0) + \
                (N_ACTIONS if hint else 0)

    @property
    def dim(self) -> int:
        return self.member_dim + self.pair_dim

    def __call__(self, view: View) -> Tokens:
        cfg = self.cfg
        h, w = cfg.height, cfg.width
        f32 = np.float32
        msgs = view.msgs
        groups, n = view.receivers.shape
        i_np, g_np = np.nonzero(view.receivers.T)  # id-major receivers
        heard = view.hears[g_np, i_np]  # [R, N]
        r_np, j = np.nonzero(heard)  # canonical pairs: receiver-major, members in id order
        lens = heard.sum(1).astype(np.int64)
        g, i = g_np[r_np], i_np[r_np]

        mrow = (g * n + j).astype(np.int64)  # member's row
        pos = msgs.pos.reshape(groups * n, 2).astype(np.int64)
        # member parts of the rows some receiver heard (all of them in a batch; a robot process
        # hears a few of N): the same values, zero in rows no pair reads
        used: np.ndarray | slice = slice(None)
        if 2 * len(mrow) < groups * n:
            seen = np.zeros(groups * n, dtype=bool)
            seen[mrow] = True
            used = np.flatnonzero(seen)
        code = msgs.patch.reshape(groups * n, -1)[used]
        if code.dtype == np.uint8:  # the three planes of each code, looked up
            planes = self.code_planes[:, code].transpose(1, 0, 2).reshape(len(code), -1)
        else:
            low = code & 3
            planes = np.concatenate([low == 1, low == 2, (code & 4) != 0], axis=1).astype(f32)
        feats = np.concatenate([planes, pos[used].astype(f32) / self.norm], axis=1)
        if isinstance(used, slice):
            member = feats
        else:
            member = np.zeros((groups * n, feats.shape[1]), dtype=f32)
            member[used] = feats

        scale = np.array([h, w], dtype=f32)
        rpos = pos[g * n + i]  # receiver's cell [P, 2]
        rel = (pos[mrow] - rpos).astype(f32) / scale
        # the member's visited bitmap in the crop x crop window on the receiver (-1 off-grid)
        cell, inside = self.window(rpos[:, 0], rpos[:, 1])
        bits = msgs.visited.reshape(groups * n, h * w)[mrow[:, None], cell]
        crop = np.where(inside, bits, -1).astype(f32)
        recent = msgs.recent.reshape(groups * n, -1)[mrow].astype(np.int64)  # [P, L]
        valid = recent >= 0
        ry = recent // w
        ryx = np.empty(recent.shape + (2,), dtype=f32)
        ryx[..., 0], ryx[..., 1] = ry - rpos[:, 0:1], recent - ry * w - rpos[:, 1:2]
        ryx = (ryx / scale * valid[..., None]).reshape(len(j), -1)
        pair = np.concatenate([crop, ryx, valid.astype(f32), rel, (i == j).astype(f32)[:, None],
                               np.full((len(j), 1), view.tick / cfg.horizon, dtype=f32)], axis=1)
        self_pos = (heard & (np.arange(n)[None, :] < i_np[:, None])).sum(1).astype(np.int64)
        own = None
        if self.team_pool:
            at = pos[g_np * n + i_np]
            if self.memory:
                if view.team_visited is None:
                    raise ValueError("this network reads the team memory, but the view has none "
                                     "(the policy's remember() sets it)")
                union = view.team_visited[g_np, i_np]
            else:
                union = heard_union(view)[g_np, i_np]
            own = self._team(union, at)
            if self.belief:
                idx = self._belief_rows(view, g_np, i_np)
                own = np.concatenate([own, self._belief(view.belief, idx, at)], axis=1)
                if self.hint is not None:
                    moves = self.hint.first_moves(view, view.belief)[idx]
                    own = np.concatenate([own, moves.astype(np.float32)], axis=1)
        return Tokens(member_feats=member, pair_member=mrow, pair_feats=pair, lens=lens,
                      start=np.cumsum(lens) - lens, self_pos=self_pos,
                      group=g_np.astype(np.int64), robot=i_np.astype(np.int64), n=n,
                      own_feats=own)

    def _team(self, union: np.ndarray, where: np.ndarray) -> np.ndarray:
        """Own features [R, Fo] of receivers at cell `where` [R, 2] whose team-visited map is
        `union` [R, H*W] bool, as a crop and a coarse map.

        Block sums of the not-yet-explored map come from its summed-area table at the block
        edges clamped to the grid, so off-grid cells count as explored (nothing to find there).
        """
        h, w = self.cfg.height, self.cfg.width
        p, k = self.block, self.team_k
        r = len(union)
        rows = np.arange(r)[:, None]
        y, x = where[:, 0], where[:, 1]
        cell, inside = self.window(y, x)
        crop = np.where(inside, union[rows, cell], -1).astype(np.float32)
        sat = np.zeros((r, h + 1, w + 1), dtype=np.float32)
        sat[:, 1:, 1:] = (~union).reshape(r, h, w).astype(np.float32).cumsum(1).cumsum(2)
        s = sat.reshape(r, -1)[rows, self.corners(y, x)[0]].reshape(r, k + 1, k + 1)
        blocks = s[:, 1:, 1:] - s[:, :-1, 1:] - s[:, 1:, :-1] + s[:, :-1, :-1]
        return np.concatenate([crop, blocks.reshape(r, k * k) / np.float32(p * p)], axis=1)

    @staticmethod
    def _belief_rows(view: View, g: np.ndarray, i: np.ndarray) -> np.ndarray:
        """Row of the view's belief snapshot of each receiver (g, i)."""
        snap = view.belief
        if snap is None:
            raise ValueError("this network reads the belief map, but the view has none "
                             "(the policy's remember() sets it)")
        n = view.receivers.shape[1]
        row = np.full(view.groups * n, -1, dtype=np.int64)
        row[snap.g * n + snap.i] = np.arange(snap.size)
        idx = row[g * n + i]
        if (idx < 0).any():
            raise ValueError("the view's belief lacks a receiver")
        return idx

    def _belief(self, snap: Snapshot, idx: np.ndarray, where: np.ndarray) -> np.ndarray:
        """Belief features [R, 2 crop^2] of the receivers at rows `idx` of the belief snapshot,
        at cells `where` [R, 2]: the window of known blocks (1 / 0, -1 off-grid) and of the path
        length to the nearest frontier target through cells not known to be blocks, as
        min(d, BELIEF_CAP) / BELIEF_CAP (1: that far or unreachable, blocks included; -1
        off-grid)."""
        r = len(idx)
        rows = np.arange(r)[:, None]
        cell, inside = self.window(where[:, 0], where[:, 1])
        block = (snap.known[idx] == BLOCK).reshape(r, -1)[rows, cell]
        dist = distance_fields(snap.passable_bits[idx], snap.targets_bits[idx], self.cfg.width,
                               max_steps=BELIEF_CAP).reshape(r, -1)[rows, cell]
        near = np.minimum(dist, BELIEF_CAP).astype(np.float32) / np.float32(BELIEF_CAP)
        return np.concatenate([np.where(inside, block, -1).astype(np.float32),
                               np.where(inside, near, np.float32(-1))], axis=1)
