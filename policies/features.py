"""The torch side of the member tokens: `Members` (the numpy `policies.infer.tokens.Tokens` as
tensors, zero-copy), the token embedding and the bidirectional GRU the trainable networks use.
The features themselves are computed once, in numpy (policies.infer.tokens), for acting and
training alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn.utils.rnn import PackedSequence

from policies.infer.tokens import Featurizer, ModelConfig, Tokens

__all__ = ["Featurizer", "Members", "ModelConfig", "Sequences", "TokenEmbed", "bigru", "rows"]


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

    @staticmethod
    def of(t: Tokens) -> Members:
        """The tokens as tensors (sharing their memory)."""
        f = torch.from_numpy
        return Members(member_feats=f(t.member_feats), pair_member=f(t.pair_member),
                       pair_feats=f(t.pair_feats), lens=f(t.lens), start=f(t.start),
                       self_pos=f(t.self_pos), group=t.group, robot=t.robot, n=t.n,
                       own_feats=None if t.own_feats is None else f(t.own_feats))


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
