"""CommAttn (Geng et al. 2019, section 3): BiGRU encoder over the neighbourhood, O(N^2) attention,
and a GRU decoder chained over robot ids through the predecessor's hidden-state message.

Receiver i (SPEC section 3): its heard members S_i, ordered by id, are encoded by a bidirectional
GRU into h_j = [h_fwd_j, h_bwd_j]; with (s_{i-1}, a_{i-1}) the predecessor's decoder state and
action (learned s_0 and a 'no action' token where p(i) = -1),

    e_ij = m(s_{i-1}, h_j) = v^T tanh(W_s s_{i-1} + W_h h_j + b)     (matching net, a small MLP)
    alpha_ij = softmax_j(e_ij) over S_i,   c_i = sum_j alpha_ij h_j
    s_i = GRUCell([emb(a_{i-1}), c_i], s_{i-1})
    p(a_i | a_<i) = softmax(g(emb(a_{i-1}), s_i, c_i)),   b = value([s_i, c_i]).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from policies.features import Members, TokenEmbed, bigru, rows
from policies.infer.nets import CommAttnConfig, NumpyCommAttn, hint_prior
from policies.learned import LearnedPolicy
from world.core import N_ACTIONS

NO_ACTION = N_ACTIONS  # action-embedding index used where there is no predecessor


@dataclass
class Encoded:
    """Encoder output of R receivers over their compact members."""

    h: torch.Tensor  # [R, M, 2H]
    keys: torch.Tensor  # [R, M, K] W_h h_j + b, precomputed for the matching net
    mask: torch.Tensor  # [R, M] bool
    mine: torch.Tensor  # [R, 2H (+E)] the receiver's own h_i (and token embedding x_i)
    prior: torch.Tensor | None = None  # [R, 9] added to the logits (model hint_prior), or None


@dataclass
class DecodeOut:
    logits: torch.Tensor  # [R, 9]
    value: torch.Tensor  # [R]
    state: torch.Tensor  # [R, S]
    context: torch.Tensor  # [R, 2H]
    alpha: torch.Tensor  # [R, M] attention weights (0 on padding)


class CommAttn(nn.Module):
    """The network; `encode` once per receiver, `decode` one chain step for a set of receivers."""

    chained = True

    def __init__(self, cfg: CommAttnConfig, member_dim: int, pair_dim: int,
                 own_dim: int = 0) -> None:
        super().__init__()
        e, h, s, k, a = cfg.embed, cfg.hidden, cfg.state, cfg.match, cfg.action_embed
        self.cfg = cfg
        self.embed = TokenEmbed(member_dim, pair_dim, e, own_dim)
        self.gru = nn.GRU(e, h, batch_first=True, bidirectional=True)
        self.s0 = nn.Parameter(torch.zeros(s))
        self.action = nn.Embedding(N_ACTIONS + 1, a)
        self.match_s = nn.Linear(s, k, bias=False)
        self.match_h = nn.Linear(2 * h, k)
        self.match_v = nn.Linear(k, 1, bias=False)
        own = 2 * h + e if cfg.self_input else 0
        self.cell = nn.GRUCell(a + 2 * h, s)
        self.policy = nn.Sequential(nn.Linear(a + s + 2 * h + own, s), nn.ReLU(),
                                    nn.Linear(s, N_ACTIONS))
        self.value = nn.Sequential(nn.Linear(s + 2 * h + own, s), nn.ReLU(), nn.Linear(s, 1))

    @property
    def state_size(self) -> int:
        return self.cfg.state

    def encode(self, members: Members) -> Encoded:
        x = self.embed(members)
        seq = bigru(self.gru, x, members)
        _, mask = members.pad_index(0)
        at = seq.where[torch.arange(members.receivers), members.self_pos]
        mine = rows(seq.flat, at)
        if self.cfg.self_input:  # also the receiver's own token embedding (a skip past the BiGRU)
            mine = torch.cat([mine, rows(x, members.start + members.self_pos)], dim=-1)
        keys = seq.padded(self.match_h(seq.flat))
        return Encoded(h=seq.padded(), keys=keys, mask=mask, mine=mine,
                       prior=hint_prior(self.cfg, members.own_feats))

    def decode(self, enc: Encoded, s_prev: torch.Tensor, a_prev: torch.Tensor,
               with_value: bool = True) -> DecodeOut:
        """One decoder step for the receivers of `enc` given (s_{p(i)}, a_{p(i)})."""
        energy = self.match_v(torch.tanh(enc.keys + self.match_s(s_prev)[:, None, :]))[..., 0]
        alpha = torch.softmax(energy.masked_fill(~enc.mask, float("-inf")), dim=1)
        context = torch.bmm(alpha[:, None, :], enc.h)[:, 0]
        emb = self.action(a_prev)
        own = [enc.mine] if self.cfg.self_input else []
        state = self.cell(torch.cat([emb, context], dim=-1), s_prev)
        logits = self.policy(torch.cat([emb, state, context, *own], dim=-1))
        if enc.prior is not None:
            logits = logits + enc.prior
        value = self.baseline(state, context, enc.mine) if with_value else logits.new_zeros(0)
        return DecodeOut(logits, value, state, context, alpha)

    def baseline(self, state: torch.Tensor, context: torch.Tensor,
                 mine: torch.Tensor) -> torch.Tensor:
        """b(s) of receivers [R] from their decoder state, context and own encoding."""
        own = [mine] if self.cfg.self_input else []
        return self.value(torch.cat([state, context, *own], dim=-1))[:, 0]

    def chain(self, enc: Encoded, robot: np.ndarray, pred: torch.Tensor,
              choose: Callable[[slice, torch.Tensor], torch.Tensor],
              ) -> tuple[DecodeOut, torch.Tensor]:
        """Decode every receiver in id order (rows must be id-major, as `Members` are); receiver r
        takes the state and action of row `pred[r]` (-1: none, s_0 and the no-action token).
        `choose(rows, logits)` gives the actions of a block of rows. Returns the step outputs and
        the actions in row order."""
        if len(robot) and (np.diff(robot) < 0).any():
            raise ValueError("chain needs receivers in id-major order")
        sizes = np.bincount(robot, minlength=1).tolist() if len(robot) else []
        priors = enc.prior.split(sizes) if enc.prior is not None else [None] * len(sizes)
        blocks = zip(sizes, enc.h.split(sizes), enc.keys.split(sizes), enc.mask.split(sizes),
                     enc.mine.split(sizes), priors, strict=True)
        states: list[torch.Tensor] = []
        actions: list[torch.Tensor] = []
        outs: list[DecodeOut] = []
        lo = 0
        for size, h, keys, mask, mine, prior in blocks:
            if size == 0:
                continue
            pr = pred[lo:lo + size]
            has = pr >= 0
            s_prev = self.s0.expand(size, -1)
            a_prev = torch.full((size,), NO_ACTION, dtype=torch.long)
            if bool(has.any()):
                at = pr.clamp(0, lo - 1)
                s_prev = torch.where(has[:, None], rows(torch.cat(states), at), s_prev)
                a_prev = torch.where(has, rows(torch.cat(actions), at), a_prev)
            out = self.decode(Encoded(h, keys, mask, mine, prior), s_prev, a_prev,
                              with_value=False)
            states.append(out.state)
            actions.append(choose(slice(lo, lo + size), out.logits))
            outs.append(out)
            lo += size
        if not outs:
            z = enc.h.new_zeros
            return DecodeOut(z(0, N_ACTIONS), z(0), z(0, self.cfg.state), z(0, enc.h.shape[2]),
                             z(0, enc.h.shape[1])), torch.zeros(0, dtype=torch.long)
        def cat(name: str) -> torch.Tensor:
            return torch.cat([getattr(o, name) for o in outs])

        state, context = cat("state"), cat("context")
        value = self.baseline(state, context, enc.mine)  # off the chain: one batched call
        return DecodeOut(cat("logits"), value, state, context, cat("alpha")), torch.cat(actions)


class CommAttnPolicy(LearnedPolicy):
    name = "commattn"
    chained = True
    config_cls = CommAttnConfig
    numpy_cls = NumpyCommAttn
    net_cls = CommAttn
