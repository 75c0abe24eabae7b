"""VAIN (Hoshen 2017), receiver-centric: every member j of S_i gets an embedding e_j and an
attention vector a_j; receiver i pools the others with the kernel exp(-||a_i - a_j||^2), O(N).

    comm_i = sum_{j in S_i, j != i} softmax_j(-||a_i - a_j||^2) e_j   (0 when i is alone)
    logits, value = heads([e_i, comm_i])
"""

from __future__ import annotations

import torch
from torch import nn

from policies.features import Members, TokenEmbed
from policies.infer.nets import NumpyVAIN, VAINConfig
from policies.learned import LearnedPolicy
from world.core import N_ACTIONS


class VAIN(nn.Module):
    chained = False

    def __init__(self, cfg: VAINConfig, member_dim: int, pair_dim: int,
                 own_dim: int = 0) -> None:
        super().__init__()
        h = cfg.hidden
        self.cfg = cfg
        self.encoder = nn.Sequential(nn.Linear(h, h), nn.ReLU())
        self.embed = TokenEmbed(member_dim, pair_dim, h, own_dim)
        self.attend = nn.Linear(h, cfg.attention)
        self.decoder = nn.Sequential(nn.Linear(2 * h, h), nn.ReLU())
        self.policy = nn.Linear(h, N_ACTIONS)
        self.value = nn.Linear(h, 1)

    def forward(self, members: Members) -> tuple[torch.Tensor, torch.Tensor]:
        """Members [R, M, F] -> logits [R, 9], value [R]."""
        e, mask = members.padded(self.encoder(self.embed(members)))
        rows = torch.arange(e.shape[0])
        a = self.attend(e)
        e_i, a_i = e[rows, members.self_pos], a[rows, members.self_pos]
        d2 = ((a - a_i[:, None, :]) ** 2).sum(-1)
        others = mask.clone()
        others[rows, members.self_pos] = False
        w = torch.softmax((-d2).masked_fill(~others, -1e9), dim=1) * others  # alone: no message
        comm = (w[..., None] * e).sum(1)
        z = self.decoder(torch.cat([e_i, comm], dim=-1))
        return self.policy(z), self.value(z)[:, 0]


class VAINPolicy(LearnedPolicy):
    name = "vain"
    config_cls = VAINConfig
    numpy_cls = NumpyVAIN
    net_cls = VAIN
