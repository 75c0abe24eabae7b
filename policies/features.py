"""Member tokens of the learned policies: what receiver i reads about member j of its neighbourhood.

A token for (receiver i, member j in S_i) has two parts:

- a *member* part, the same for every receiver, computed once per (group, robot): j's v x v
  patch as three one-hot planes (block, off-grid, robot) and j's absolute position in [0, 1];
- a *pair* part, relative to the receiver: an egocentric `crop x crop` window of j's visited
  bitmap centred on the *receiver's* cell (1 visited, 0 not, -1 off-grid), j's recent positions
  relative to i (dy / H, dx / W, valid flag), j's position relative to i, an is-self flag and
  the tick fraction t / T;
- optionally (`team_pool > 0`) an *own* part per receiver, added to its own token only: the
  team map it can assemble from the messages it heard this tick, i.e. the union U_i of its
  members' visited bitmaps, as an egocentric `crop x crop` window (1 / 0 / -1 as above) and as a
  coarse egocentric map of the whole grid, the fraction of cells not in U_i in each
  `team_pool x team_pool` block of a window wide enough to cover the grid from any cell. Without
  it a receiver can only see 4 cells of explored map around it and has no sense of where the
  unexplored area lies beyond; frontier planners read the whole belief map.

Only heard pairs exist: `Members` lists them receiver by receiver, members in id order (the
canonical pair order), so an unheard robot never enters a computation. Receivers are id-major
(all robot-0 receivers of every group, then robot 1, ...), the order CommAttn's chain decodes
in. `Members.dense()` gives the [R, N, F] tokens and [R, N] mask view of the same data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn.utils.rnn import PackedSequence

from world.config import ConfigError, WorldConfig
from world.decentral import View, heard_union


@dataclass
class ModelConfig:
    """The feature settings every learned network shares (each network's config extends it)."""

    crop: int = 9
    """Side of the egocentric window of each member's visited bitmap (see policies.features)."""
    team_pool: int = 3
    """Block size of the coarse team map added to the receiver's own token (0: no team map;
    checkpoints older than this field load with 0). See policies.features."""
    team_memory: bool = True
    """Build the team map from the receiver's memory of every bitmap heard this episode
    (world.decentral.TeamMemory) instead of this tick's messages only, so a lost message costs
    one teammate's latest steps, not its whole map. Changes no weight shape; no effect without
    the team map; checkpoints older than this field load with it off."""

@dataclass
class Members:
    """Heard (receiver, member) pairs of R receivers in G groups of N robot slots."""

    member_feats: torch.Tensor  # [G*N, Fm] per-member part, row g*N + j
    pair_member: torch.Tensor  # [P] int64 row of member_feats of each pair
    pair_feats: torch.Tensor  # [P, Fp] receiver-relative part
    lens: torch.Tensor  # [R] int64 |S_i| (>= 1: a receiver hears itself)
    start: torch.Tensor  # [R] int64 first pair of each receiver (its members follow in id order)
    self_pos: torch.Tensor  # [R] int64 slot of the receiver among its own members
    group: np.ndarray  # [R] int64
    robot: np.ndarray  # [R] int64
    n: int  # robot slots N
    own_feats: torch.Tensor | None = None  # [R, Fo] per-receiver team map (team_pool > 0)

    @property
    def receivers(self) -> int:
        return len(self.group)

    @property
    def width(self) -> int:
        """Largest neighbourhood M."""
        return int(self.lens.max()) if self.receivers else 1

    def pad_index(self, fill: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Pair index [R, M] of each receiver's slots (`fill` past its end) and the mask [R, M]."""
        slots = torch.arange(self.width)[None, :]
        mask = slots < self.lens[:, None]
        return torch.where(mask, self.start[:, None] + slots, torch.full_like(slots, fill)), mask

    def padded(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-pair rows [P, D] -> [R, M, D] (zeros past each neighbourhood) and mask [R, M]."""
        idx, mask = self.pad_index(x.shape[0])
        return rows(torch.cat([x, x.new_zeros(1, x.shape[1])]), idx), mask

    def dense(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Tokens [R, N, F] with slot j = robot j (zero where unheard) and the mask [R, N]."""
        member_ids = (self.pair_member % self.n)
        receiver = torch.repeat_interleave(torch.arange(self.receivers), self.lens)
        tokens = torch.cat([self.member_feats[self.pair_member], self.pair_feats], dim=1)
        out = tokens.new_zeros(self.receivers, self.n, tokens.shape[1])
        out[receiver, member_ids] = tokens
        mask = torch.zeros(self.receivers, self.n, dtype=torch.bool)
        mask[receiver, member_ids] = True
        return out, mask

    @staticmethod
    def cat(parts: list[Members]) -> Members:
        """Members of several views as one batch (groups renumbered), re-sorted id-major."""
        goff = np.cumsum([0] + [len(p.member_feats) // p.n for p in parts])
        poff = np.cumsum([0] + [len(p.pair_member) for p in parts])
        group = np.concatenate([p.group + o for p, o in zip(parts, goff[:-1], strict=True)])
        robot = np.concatenate([p.robot for p in parts])
        order = np.lexsort((group, robot))
        pick = torch.from_numpy(order)
        n = parts[0].n
        return Members(
            member_feats=torch.cat([p.member_feats for p in parts]),
            pair_member=torch.cat([p.pair_member + int(o) * n
                                   for p, o in zip(parts, goff[:-1], strict=True)]),
            pair_feats=torch.cat([p.pair_feats for p in parts]),
            lens=torch.cat([p.lens for p in parts])[pick],
            start=torch.cat([p.start + int(o)
                             for p, o in zip(parts, poff[:-1], strict=True)])[pick],
            self_pos=torch.cat([p.self_pos for p in parts])[pick],
            group=group[order], robot=robot[order], n=n,
            own_feats=(None if parts[0].own_feats is None
                       else torch.cat([p.own_feats for p in parts])[pick]),
        )


def rows(x: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """x[index] for row indices of any shape via index_select (much faster than advanced
    indexing on CPU, and its backward is an index_add rather than a sorting index_put)."""
    return x.index_select(0, index.reshape(-1)).view(*index.shape, *x.shape[1:])


class TokenEmbed(nn.Module):
    """relu(W_m member + W_p pair [+ W_o own on the receiver's own pair] + b) per heard pair; the
    member part is embedded once per robot and gathered."""

    def __init__(self, member_dim: int, pair_dim: int, out: int, own_dim: int = 0) -> None:
        super().__init__()
        self.member = nn.Linear(member_dim, out)
        self.pair = nn.Linear(pair_dim, out, bias=False)
        self.own = nn.Linear(own_dim, out, bias=False) if own_dim else None

    def forward(self, m: Members) -> torch.Tensor:
        """[P, out] in canonical pair order."""
        x = rows(self.member(m.member_feats), m.pair_member) + self.pair(m.pair_feats)
        if self.own is not None:
            if m.own_feats is None:
                raise ValueError("this network reads team-map features; build Members with a "
                                 "Featurizer of team_pool > 0")
            x = x.index_add(0, m.start + m.self_pos, self.own(m.own_feats))
        return torch.relu(x)


@dataclass
class Sequences:
    """Per-pair outputs of a recurrence in its own row order, and where each receiver's slots
    are."""

    flat: torch.Tensor  # [P, D]
    where: torch.Tensor  # [R, M] row of flat for (receiver, slot); P past the neighbourhood

    def padded(self, x: torch.Tensor | None = None) -> torch.Tensor:
        """`flat` (or any [P, D'] aligned with it) as [R, M, D'], zeros past each neighbourhood."""
        x = self.flat if x is None else x
        return rows(torch.cat([x, x.new_zeros(1, x.shape[1])]), self.where)


def bigru(gru: nn.GRU, x: torch.Tensor, m: Members) -> Sequences:
    """Bidirectional GRU over each receiver's members in id order: pairs [P, E] -> [P, 2H].

    With gradients, receivers are bucketed by neighbourhood size, so every sequence of a bucket
    has the same length: no padding ever enters a recurrence (both directions start at the
    receiver's own first / last member) and the plain, unpacked GRU runs (its backward is fast on
    CPU, a packed one's is not). Without gradients one packed call does the same (fewer calls).
    """
    if not torch.is_grad_enabled():
        return _bigru_packed(gru, x, m)
    lens, start = m.lens, m.start
    order = torch.argsort(lens, stable=True)
    sizes, counts = torch.unique_consecutive(lens[order], return_counts=True)
    sizes_l, counts_l = sizes.tolist(), counts.tolist()
    # one gather puts every bucket's sequences, [count, size] each, back to back
    seq_start = start[order]
    within = torch.cat([torch.arange(s).repeat(c)
                        for s, c in zip(sizes_l, counts_l, strict=True)])
    first = torch.repeat_interleave(seq_start, lens[order])
    inputs = rows(x, first + within).split(
        [s * c for s, c in zip(sizes_l, counts_l, strict=True)])
    outs = [gru(inp.view(c, s, -1))[0].reshape(c * s, -1)
            for inp, s, c in zip(inputs, sizes_l, counts_l, strict=True)]
    # pair (receiver order[k], slot j) sits at row offset[k] + j of the concatenated outputs
    offset = torch.cumsum(lens[order], 0) - lens[order]
    where = torch.full((m.receivers, m.width), x.shape[0], dtype=torch.long)
    slots = torch.arange(m.width)[None, :]
    valid = slots < lens[order][:, None]
    where[order] = torch.where(valid, offset[:, None] + slots, where[order])
    return Sequences(torch.cat(outs), where)


def _bigru_packed(gru: nn.GRU, x: torch.Tensor, m: Members) -> Sequences:
    """`bigru` as one packed call (time-major, longest neighbourhood first)."""
    lens = m.lens
    rank = torch.empty_like(lens)
    rank[torch.argsort(-lens, stable=True)] = torch.arange(m.receivers)
    batch_sizes = (lens[None, :] > torch.arange(m.width)[:, None]).sum(1)
    offs = torch.cumsum(batch_sizes, 0) - batch_sizes
    idx, mask = m.pad_index(0)
    where = torch.where(mask, offs[None, :] + rank[:, None], torch.full_like(idx, x.shape[0]))
    order = torch.empty(x.shape[0], dtype=torch.long)
    order[where[mask]] = idx[mask]  # packed position -> canonical pair
    out, _ = gru(PackedSequence(rows(x, order), batch_sizes))
    return Sequences(out.data, where)


class Featurizer:
    """Turns a View into `Members` for its receivers; member_dim + pair_dim is the token width."""

    def __init__(self, cfg: WorldConfig, crop: int = 9, team_pool: int = 0,
                 memory: bool = False) -> None:
        if crop < 1 or crop % 2 == 0:
            raise ConfigError(f"crop must be a positive odd number, got {crop}")
        if team_pool < 0:
            raise ConfigError(f"team_pool must be >= 0, got {team_pool}")
        self.cfg = cfg
        self.crop = crop
        c = crop // 2
        self.hc, self.wc = cfg.height + 2 * c, cfg.width + 2 * c
        dy, dx = np.meshgrid(np.arange(crop), np.arange(crop), indexing="ij")
        self.window = torch.from_numpy((dy * self.wc + dx).ravel())  # from the window's corner
        self.member_dim = 3 * cfg.vision * cfg.vision + 2
        self.pair_dim = crop * crop + 3 * cfg.recent_len + 2 + 1 + 1
        self.team_pool = team_pool
        # the team map from view.team_visited (a TeamMemory), not this tick; nothing to
        # remember without a team map
        self.memory = memory and team_pool > 0
        self.own_dim = 0
        if team_pool:
            # the coarse window: k x k blocks of p x p cells, its corner `team_half` cells up and
            # left of the receiver, wide enough to cover the grid from any cell
            p = team_pool
            k = -(-(2 * max(cfg.height, cfg.width) - 1) // p)
            self.team_k, self.team_half = k, (k * p) // 2
            self.edges = torch.arange(k + 1) * p - self.team_half  # block edges, from the cell
            self.dy = torch.from_numpy(dy.ravel() - c)
            self.dx = torch.from_numpy(dx.ravel() - c)
            self.own_dim = crop * crop + k * k

    @property
    def dim(self) -> int:
        return self.member_dim + self.pair_dim

    def __call__(self, view: View) -> Members:
        cfg = self.cfg
        h, w, c = cfg.height, cfg.width, self.crop // 2
        msgs = view.msgs
        groups, n = view.receivers.shape
        i_np, g_np = np.nonzero(view.receivers.T)  # id-major receivers
        heard = view.hears[g_np, i_np]  # [R, N]
        r_np, j_np = np.nonzero(heard)  # canonical pairs: receiver-major, members in id order
        lens = heard.sum(1)
        g, i, j = (torch.from_numpy(a) for a in (g_np[r_np], i_np[r_np], j_np))

        code = torch.from_numpy(msgs.patch.reshape(groups * n, -1))
        low = code & 3
        pos = torch.from_numpy(msgs.pos).reshape(groups * n, 2)
        norm = torch.tensor([max(h - 1, 1), max(w - 1, 1)], dtype=torch.float32)
        member = torch.cat([low == 1, low == 2, (code & 4) != 0], dim=1).float()
        member = torch.cat([member, pos.float() / norm], dim=1)

        scale = torch.tensor([h, w], dtype=torch.float32)
        mrow = g * n + j  # member's row
        rpos = rows(pos, g * n + i)  # receiver's cell [P, 2]
        rel = (rows(pos, mrow) - rpos).float() / scale
        vpad = torch.full((groups * n, self.hc, self.wc), -1, dtype=torch.int8)
        vpad[:, c:c + h, c:c + w] = torch.from_numpy(msgs.visited).view(groups * n, h, w)
        corner = mrow * (self.hc * self.wc) + rpos[:, 0] * self.wc + rpos[:, 1]
        crop = rows(vpad.view(-1), corner[:, None] + self.window[None, :]).float()
        recent = rows(torch.from_numpy(msgs.recent).reshape(groups * n, -1), mrow)  # [P, L]
        valid = recent >= 0
        ry = torch.div(recent, w, rounding_mode="floor")
        ryx = (torch.stack([ry, recent - ry * w], dim=-1) - rpos[:, None, :]).float() / scale
        ryx = (ryx * valid[..., None]).flatten(1)
        pair = torch.cat([crop, ryx, valid.float(), rel, (i == j).float()[:, None],
                          torch.full((len(j), 1), view.tick / cfg.horizon)], dim=1)
        lens_t = torch.from_numpy(lens)
        self_pos = torch.from_numpy((heard & (np.arange(n)[None, :] < i_np[:, None])).sum(1))
        own = None
        if self.team_pool:
            at = rows(pos, torch.from_numpy(g_np * n + i_np))
            if self.memory:
                if view.team_visited is None:
                    raise ValueError("this network reads the team memory, but the view has none "
                                     "(LearnedPolicy.remember sets it)")
                union = torch.from_numpy(view.team_visited[g_np, i_np])
            else:
                union = torch.from_numpy(heard_union(view)[g_np, i_np])
            own = self._team(union, at)
        return Members(member_feats=member, pair_member=mrow, pair_feats=pair, lens=lens_t,
                       start=torch.cumsum(lens_t, 0) - lens_t, self_pos=self_pos,
                       group=g_np, robot=i_np, n=n, own_feats=own)

    def _team(self, union: torch.Tensor, where: torch.Tensor) -> torch.Tensor:
        """Own features [R, Fo] of receivers at cell `where` [R, 2] whose team-visited map is
        `union` [R, H*W] bool, as a crop and a coarse map.

        Block sums of the not-yet-explored map come from its summed-area table at the block
        edges clamped to the grid, so off-grid cells count as explored (nothing to find there).
        """
        cfg, p, k = self.cfg, self.team_pool, self.team_k
        h, w = cfg.height, cfg.width
        r = len(union)
        y, x = where[:, 0:1], where[:, 1:2]
        cy, cx = y + self.dy[None, :], x + self.dx[None, :]
        inside = (cy >= 0) & (cy < h) & (cx >= 0) & (cx < w)
        cell = cy.clamp(0, h - 1) * w + cx.clamp(0, w - 1)
        crop = torch.where(inside, union.gather(1, cell).float(), -1.0)
        sat = torch.zeros(r, h + 1, w + 1)
        sat[:, 1:, 1:] = (~union).view(r, h, w).float().cumsum(1).cumsum(2)
        ey = (y + self.edges[None, :]).clamp(0, h)  # [R, k+1]
        ex = (x + self.edges[None, :]).clamp(0, w)
        at = (ey[:, :, None] * (w + 1) + ex[:, None, :]).view(r, -1)
        s = sat.view(r, -1).gather(1, at).view(r, k + 1, k + 1)
        blocks = s[:, 1:, 1:] - s[:, :-1, 1:] - s[:, 1:, :-1] + s[:, :-1, :-1]
        return torch.cat([crop, blocks.reshape(r, k * k) / (p * p)], dim=1)
