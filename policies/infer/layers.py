"""The layers of the learned networks in numpy float32, with torch's weight names, shapes and
equations (nn.Linear, nn.Embedding, nn.GRU, nn.GRUCell), for inference without torch.

`Weights` is a flat {name: array} dict in `state_dict` order and naming; each layer reads its
arrays by prefix. Tests check every layer and every network against torch (within 1e-5).
"""

from __future__ import annotations

import numpy as np

from policies.infer.tokens import Tokens

Weights = dict[str, np.ndarray]


def linear(w: Weights, name: str, x: np.ndarray) -> np.ndarray:
    """nn.Linear `name` applied to x [..., in]."""
    y = x @ w[f"{name}.weight"].T
    bias = w.get(f"{name}.bias")
    return y if bias is None else y + bias


def relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, np.float32(0))


def sigmoid(x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Logistic function without overflow (tanh form: tanh(x / 2) / 2 + 1 / 2); with `out`, in
    place there (the GRU's gates: no allocation on a robot's [1, K] rows)."""
    out = np.multiply(x, np.float32(0.5), out=out)
    np.tanh(out, out=out)
    out *= np.float32(0.5)
    out += np.float32(0.5)
    return out


def softmax(x: np.ndarray, axis: int = -1, finite: bool = False) -> np.ndarray:
    """Softmax along `axis`; rows of all -inf give 0/0 = nan, as torch's does (`finite`: the
    caller knows there are none, which skips the error-state guard: it costs what the
    arithmetic costs on a robot's one row)."""
    if finite:
        e = np.exp(x - x.max(axis=axis, keepdims=True))
        e /= e.sum(axis=axis, keepdims=True)
        return e
    with np.errstate(invalid="ignore"):
        e = np.exp(x - x.max(axis=axis, keepdims=True))
        return e / e.sum(axis=axis, keepdims=True)


def log_softmax(x: np.ndarray, axis: int = -1) -> np.ndarray:
    m = x.max(axis=axis, keepdims=True)
    return x - m - np.log(np.exp(x - m).sum(axis=axis, keepdims=True))


def gru_gates(gi: np.ndarray, h: np.ndarray, w_hh: np.ndarray, b_hh: np.ndarray) -> np.ndarray:
    """One GRU step from the input's projection gi = W_ih x + b_ih [B, 3H] and the state h [B, H]
    (torch's gate order r, z, n)."""
    return gates(gi, h @ w_hh.T + b_hh, h)


def gates(gi: np.ndarray, gh: np.ndarray, h: np.ndarray) -> np.ndarray:
    """GRU gates from the input and state projections gi, gh [B, 3K] laid out (r, z, n), each
    K wide, and the state h [B, K]: torch's h' = (1 - z) n + z h, computed as n + z (h - n).
    In place where it can: a robot runs this ~20 times a decision on [1, K] rows, where each
    numpy call and allocation costs more than its arithmetic."""
    k = h.shape[1]
    rz = gi[:, :2 * k] + gh[:, :2 * k]
    sigmoid(rz, out=rz)
    n = rz[:, :k] * gh[:, 2 * k:]
    n += gi[:, 2 * k:]
    np.tanh(n, out=n)
    out = h - n
    out *= rz[:, k:]
    out += n
    return out


def gru_cell(w: Weights, name: str, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """nn.GRUCell `name`: x [B, in], h [B, H] -> [B, H]."""
    gi = x @ w[f"{name}.weight_ih"].T + w[f"{name}.bias_ih"]
    return gru_gates(gi, h, w[f"{name}.weight_hh"], w[f"{name}.bias_hh"])


def embedding(w: Weights, name: str, index: np.ndarray) -> np.ndarray:
    return w[f"{name}.weight"][index]


def token_embed(w: Weights, name: str, t: Tokens) -> np.ndarray:
    """policies.features.TokenEmbed: relu(W_m member + W_p pair [+ W_o own on the receiver's own
    pair] + b) per heard pair [P, out]."""
    x = linear(w, f"{name}.member", t.member_feats)[t.pair_member] + \
        linear(w, f"{name}.pair", t.pair_feats)
    if f"{name}.own.weight" in w:
        if t.own_feats is None:
            raise ValueError("this network reads team-map features; build Tokens with a "
                             "Featurizer of team_pool > 0")
        x[t.own_row] += linear(w, f"{name}.own", t.own_feats)  # one own row per receiver
    return relu(x)


def pack_bigru(w: Weights, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The recurrent weights of nn.GRU `name`'s two directions as one block-diagonal matrix
    [2H, 6H], columns ordered (r_f, r_b, z_f, z_b, n_f, n_b), and its bias [6H] (see `bigru`)."""
    k = w[f"{name}.weight_hh_l0"].shape[1]
    w_hh = np.zeros((2 * k, 6 * k), dtype=np.float32)  # block-diagonal, gate-interleaved
    w_hh.reshape(2, k, 3, 2, k)[0, :, :, 0] = w[f"{name}.weight_hh_l0"].T.reshape(k, 3, k)
    w_hh.reshape(2, k, 3, 2, k)[1, :, :, 1] = w[f"{name}.weight_hh_l0_reverse"].T.reshape(k, 3, k)
    b_hh = np.stack([w[f"{name}.bias_hh_l0"].reshape(3, k),
                     w[f"{name}.bias_hh_l0_reverse"].reshape(3, k)], axis=1).reshape(6 * k)
    return w_hh, b_hh


def bigru(w: Weights, name: str, x: np.ndarray, t: Tokens,
          packed: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """nn.GRU `name` (bidirectional, one layer) over each receiver's members in id order:
    pairs [P, E] -> [P, 2H] in canonical pair order. Each direction starts from zeros at the
    receiver's own first / last member; no padding enters a recurrence.

    Both directions advance in one step: the state is [h_fwd | h_bwd] [R, 2H], step s reads
    the forward input at slot s and the backward one at slot M-1-s, and one block-diagonal
    matrix projects both states, its columns ordered (r_f, r_b, z_f, z_b, n_f, n_b) so that the
    gates of both directions are contiguous (half the Python steps of one loop per direction).
    `packed` is `pack_bigru(w, name)` when the caller keeps it (built here otherwise).
    """
    p, r, m = x.shape[0], t.receivers, t.width
    xp, mask = t.padded(x)  # [R, M, E]
    k = w[f"{name}.weight_hh_l0"].shape[1]
    gi = np.empty((r, m, 3, 2, k), dtype=np.float32)  # gates of both directions, interleaved
    gi[:, :, :, 0] = (xp @ w[f"{name}.weight_ih_l0"].T + w[f"{name}.bias_ih_l0"]).reshape(
        r, m, 3, k)
    gi[:, :, :, 1] = (xp[:, ::-1] @ w[f"{name}.weight_ih_l0_reverse"].T +
                      w[f"{name}.bias_ih_l0_reverse"]).reshape(r, m, 3, k)
    gi = gi.reshape(r, m, 6 * k)
    w_hh, b_hh = packed if packed is not None else pack_bigru(w, name)
    full = bool(mask.all())  # (a robot's single receiver, or equal neighbourhoods)
    both = None if full else np.repeat(np.stack([mask, mask[:, ::-1]], axis=2), k, axis=2)
    h = np.zeros((r, 2 * k), dtype=np.float32)
    out = np.empty((r, m, 2 * k), dtype=np.float32)
    for s in range(m):
        gh = h @ w_hh
        gh += b_hh
        new = gates(gi[:, s], gh, h)
        h = new if both is None else np.where(both[:, s], new, h)
        out[:, s] = h
    both_ways = np.concatenate([out[:, :, :k], out[:, ::-1, k:]], axis=-1)
    flat = both_ways.reshape(-1, 2 * k) if full else both_ways[mask]
    assert len(flat) == p
    return flat
