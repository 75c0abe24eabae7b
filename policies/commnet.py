"""CommNet (Sukhbaatar et al. 2016), receiver-centric: receiver i runs K communication steps of
mean pooling over its own neighbourhood S_i and reads the output at its own slot.

    h^0_j = enc(x_j),   c^k_j = mean_{l in S_i, l != j} h^k_l   (0 when j is alone)
    h^{k+1}_j = tanh(H_k h^k_j + C_k c^k_j + h^0_j)            (skip connection to the encoder)
    logits, value = heads(h^K_i)
"""

from __future__ import annotations

import torch
from torch import nn

from policies.features import Members, TokenEmbed
from policies.infer.nets import CommNetConfig, NumpyCommNet
from policies.learned import LearnedPolicy
from world.core import N_ACTIONS


class CommNet(nn.Module):
    chained = False

    def __init__(self, cfg: CommNetConfig, member_dim: int, pair_dim: int,
                 own_dim: int = 0) -> None:
        super().__init__()
        h = cfg.hidden
        self.cfg = cfg
        self.encoder = TokenEmbed(member_dim, pair_dim, h, own_dim)
        self.own = nn.ModuleList(nn.Linear(h, h) for _ in range(cfg.steps))
        self.comm = nn.ModuleList(nn.Linear(h, h, bias=False) for _ in range(cfg.steps))
        self.policy = nn.Sequential(nn.Linear(h, h), nn.ReLU(), nn.Linear(h, N_ACTIONS))
        self.value = nn.Sequential(nn.Linear(h, h), nn.ReLU(), nn.Linear(h, 1))

    def forward(self, members: Members) -> tuple[torch.Tensor, torch.Tensor]:
        """Members [R, M, F] -> logits [R, 9], value [R]."""
        h0, mask = members.padded(self.encoder(members))
        m = mask[..., None].float()
        others = (members.lens - 1).clamp(min=1).float()[:, None, None]
        h = h0
        for own, comm in zip(self.own, self.comm, strict=True):
            c = ((h.sum(1, keepdim=True) - h) / others) * m
            h = torch.tanh(own(h) + comm(c) + h0) * m
        mine = h[torch.arange(h.shape[0]), members.self_pos]
        return self.policy(mine), self.value(mine)[:, 0]


class CommNetPolicy(LearnedPolicy):
    name = "commnet"
    config_cls = CommNetConfig
    numpy_cls = NumpyCommNet
    net_cls = CommNet
