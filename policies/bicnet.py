"""BicNet (Peng et al. 2017), receiver-centric: a bidirectional GRU over the members of S_i in id
order; the receiver's action and value come from the BiGRU output at its own position."""

from __future__ import annotations

import torch
from torch import nn

from policies.features import Members, TokenEmbed, bigru, rows
from policies.infer.nets import BicNetConfig, NumpyBicNet
from policies.learned import LearnedPolicy
from world.core import N_ACTIONS


class BicNet(nn.Module):
    chained = False

    def __init__(self, cfg: BicNetConfig, member_dim: int, pair_dim: int,
                 own_dim: int = 0) -> None:
        super().__init__()
        e, h = cfg.embed, cfg.hidden
        self.cfg = cfg
        self.embed = TokenEmbed(member_dim, pair_dim, e, own_dim)
        self.gru = nn.GRU(e, h, batch_first=True, bidirectional=True)
        self.policy = nn.Sequential(nn.Linear(2 * h, 2 * h), nn.ReLU(), nn.Linear(2 * h, N_ACTIONS))
        self.value = nn.Sequential(nn.Linear(2 * h, 2 * h), nn.ReLU(), nn.Linear(2 * h, 1))

    def forward(self, members: Members) -> tuple[torch.Tensor, torch.Tensor]:
        """Members [R, M, F] -> logits [R, 9], value [R]."""
        seq = bigru(self.gru, self.embed(members), members)
        mine = rows(seq.flat, seq.where[torch.arange(members.receivers), members.self_pos])
        return self.policy(mine), self.value(mine)[:, 0]


class BicNetPolicy(LearnedPolicy):
    name = "bicnet"
    config_cls = BicNetConfig
    numpy_cls = NumpyBicNet
    net_cls = BicNet
