"""Member tokens of the learned policies: what receiver i reads about member j of its neighbourhood.

For every receiver i (R of them) and every robot slot j (N, ordered by id) a token [F] built only
from j's trajectory message and i's own position, and a mask `hears[g, i, j]`. A token holds:

- j's v x v patch as three one-hot planes (block, off-grid, robot), 3 v v values;
- j's absolute position, normalised to [0, 1];
- j's trajectory seen from i: an egocentric `crop x crop` window of j's visited bitmap centred
  on the *receiver's* cell (1 visited, 0 not, -1 off-grid), and j's recent positions relative to
  i (dy / H, dx / W and a valid flag each);
- j's position relative to i, an is-self flag and the tick fraction t / T.

Per-member pieces are computed once per (group, robot) and gathered; pair pieces are one gather.
`compact` moves each receiver's heard members to the front (id order kept), which is the layout
the networks run on: unheard members never enter a computation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch.nn.utils.rnn import pack_padded_sequence, pad_packed_sequence

from world.config import WorldConfig
from world.decentral import View


@dataclass
class Tokens:
    """Dense member tokens of R receivers: slot j is robot j."""

    tokens: torch.Tensor  # [R, N, F] float32, zero where not heard
    mask: torch.Tensor  # [R, N] bool: receiver heard member j (itself included)
    group: np.ndarray  # [R] int64 group of each receiver
    robot: np.ndarray  # [R] int64 id of each receiver (group-major, id order)

    def compact(self) -> Members:
        return compact(self.tokens, self.mask, torch.from_numpy(self.robot))


@dataclass
class Members:
    """Each receiver's heard members moved to the front, in id order; M = largest neighbourhood."""

    x: torch.Tensor  # [R, M, F]
    mask: torch.Tensor  # [R, M] bool
    lens: torch.Tensor  # [R] int64 neighbourhood sizes (>= 1: a receiver hears itself)
    member: torch.Tensor  # [R, M] int64 robot id in each compact slot (-1 past the end)
    self_pos: torch.Tensor  # [R] int64 compact slot holding the receiver itself


def compact(tokens: torch.Tensor, mask: torch.Tensor, robot: torch.Tensor) -> Members:
    """Stable-move heard slots to the front: [R, N, F], [R, N] -> Members with M = max |S_i|."""
    r, n, _ = tokens.shape
    lens = mask.sum(1)
    m = int(lens.max()) if r else 1
    # heard slots first, each side in id order: sort key = (not heard) * n + id
    key = (~mask).long() * n + torch.arange(n)
    order = key.argsort(dim=1)[:, :m]
    x = tokens.gather(1, order[..., None].expand(-1, -1, tokens.shape[2]))
    cmask = torch.arange(m)[None, :] < lens[:, None]
    member = torch.where(cmask, order, torch.full_like(order, -1))
    self_pos = (mask & (torch.arange(n)[None, :] < robot[:, None])).sum(1)
    return Members(x=x, mask=cmask, lens=lens, member=member, self_pos=self_pos)


def bigru(gru: torch.nn.GRU, x: torch.Tensor, lens: torch.Tensor) -> torch.Tensor:
    """Bidirectional GRU over each receiver's compact members: [R, M, E] -> [R, M, 2H].

    Packing makes the backward direction start at each sequence's own last member, so padding
    never reaches a valid output; padded outputs are zero.
    """
    packed = pack_padded_sequence(x, lens, batch_first=True, enforce_sorted=False)
    out, _ = gru(packed)
    out, _ = pad_packed_sequence(out, batch_first=True, total_length=x.shape[1])
    return out


class Featurizer:
    """Turns a View into member tokens for its receivers; `dim` is the token width F."""

    def __init__(self, cfg: WorldConfig, crop: int = 9) -> None:
        if crop < 1 or crop % 2 == 0:
            raise ValueError(f"crop must be a positive odd number, got {crop}")
        self.cfg = cfg
        self.crop = crop
        c = crop // 2
        self.wc = cfg.width + 2 * c
        self.hc = cfg.height + 2 * c
        dy, dx = np.meshgrid(np.arange(crop), np.arange(crop), indexing="ij")
        self.window = torch.from_numpy((dy * self.wc + dx).ravel())  # from the window's corner
        v2 = cfg.vision * cfg.vision
        self.parts = {"patch": 3 * v2, "abs": 2, "crop": crop * crop, "recent": 3 * cfg.recent_len,
                      "rel": 2, "self": 1, "tick": 1}
        self.dim = sum(self.parts.values())

    def __call__(self, view: View) -> Tokens:
        cfg = self.cfg
        h, w, c = cfg.height, cfg.width, self.crop // 2
        msgs = view.msgs
        g_np, i_np = np.nonzero(view.receivers)
        g, i = torch.from_numpy(g_np), torch.from_numpy(i_np)
        groups, n = view.receivers.shape
        r = len(g_np)
        scale = torch.tensor([h, w], dtype=torch.float32)

        # per member [G, N, .]: patch planes and absolute position
        code = torch.from_numpy(msgs.patch.reshape(groups, n, -1).astype(np.int64))
        planes = torch.cat([(code & 3) == 1, (code & 3) == 2, (code & 4) != 0], dim=-1).float()
        pos = torch.from_numpy(msgs.pos.astype(np.int64))
        absolute = pos.float() / torch.tensor([max(h - 1, 1), max(w - 1, 1)], dtype=torch.float32)
        member = torch.cat([planes, absolute], dim=-1)[g]  # [R, N, .]

        # pair pieces [R, N, .]: everything relative to the receiver's cell
        rpos = pos[g, i]  # [R, 2]
        rel = (pos[g] - rpos[:, None, :]).float() / scale
        visited = torch.from_numpy(msgs.visited).view(groups, n, h, w)
        vpad = torch.full((groups, n, self.hc, self.wc), -1.0)
        vpad[:, :, c:c + h, c:c + w] = visited.float()
        corner = rpos[:, 0] * self.wc + rpos[:, 1]  # window corner in padded coordinates
        idx = (g[:, None] * n + torch.arange(n)[None, :]) * (self.hc * self.wc)  # [R, N]
        crop = vpad.view(-1)[idx[:, :, None] + (corner[:, None] + self.window[None, :])[:, None, :]]
        recent = torch.from_numpy(msgs.recent)[g]  # [R, N, L]
        valid = recent >= 0
        ry = torch.div(recent, w, rounding_mode="floor")
        rx = recent - ry * w
        ryx = (torch.stack([ry, rx], dim=-1) - rpos[:, None, None, :]).float() / scale
        ryx = ryx * valid[..., None]
        recent_f = torch.cat([ryx.flatten(2), valid.float()], dim=-1)
        is_self = (torch.arange(n)[None, :] == i[:, None]).float()[..., None]
        tick = torch.full((r, n, 1), view.tick / cfg.horizon)
        tokens = torch.cat([member, crop, recent_f, rel, is_self, tick], dim=-1)
        mask = torch.from_numpy(view.hears[g_np, i_np])
        tokens = tokens * mask[..., None]
        return Tokens(tokens=tokens, mask=mask, group=g_np, robot=i_np)
