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


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Logistic function without overflow (tanh form)."""
    return np.float32(0.5) * np.tanh(np.float32(0.5) * x) + np.float32(0.5)


def softmax(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Softmax along `axis`; rows of all -inf give 0/0 = nan, as torch's does."""
    with np.errstate(invalid="ignore"):
        e = np.exp(x - x.max(axis=axis, keepdims=True))
        return e / e.sum(axis=axis, keepdims=True)


def log_softmax(x: np.ndarray, axis: int = -1) -> np.ndarray:
    m = x.max(axis=axis, keepdims=True)
    return x - m - np.log(np.exp(x - m).sum(axis=axis, keepdims=True))


def gru_gates(gi: np.ndarray, h: np.ndarray, w_hh: np.ndarray, b_hh: np.ndarray) -> np.ndarray:
    """One GRU step from the input's projection gi = W_ih x + b_ih [B, 3H] and the state h [B, H]
    (torch's gate order r, z, n)."""
    gh = h @ w_hh.T + b_hh
    k = h.shape[1]
    r = sigmoid(gi[:, :k] + gh[:, :k])
    z = sigmoid(gi[:, k:2 * k] + gh[:, k:2 * k])
    n = np.tanh(gi[:, 2 * k:] + r * gh[:, 2 * k:])
    return (1 - z) * n + z * h


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


def bigru(w: Weights, name: str, x: np.ndarray, t: Tokens) -> np.ndarray:
    """nn.GRU `name` (bidirectional, one layer) over each receiver's members in id order:
    pairs [P, E] -> [P, 2H] in canonical pair order. Each direction starts from zeros at the
    receiver's own first / last member; no padding enters a recurrence."""
    (idx, mask), p = t.pad_index(x.shape[0]), x.shape[0]
    xp = np.concatenate([x, np.zeros((1, x.shape[1]), x.dtype)])[idx]  # [R, M, E]
    outs = []
    for suffix, steps in (("l0", range(t.width)), ("l0_reverse", range(t.width - 1, -1, -1))):
        w_hh, b_hh = w[f"{name}.weight_hh_{suffix}"], w[f"{name}.bias_hh_{suffix}"]
        gi = xp @ w[f"{name}.weight_ih_{suffix}"].T + w[f"{name}.bias_ih_{suffix}"]
        h = np.zeros((t.receivers, w_hh.shape[1]), dtype=np.float32)
        out = np.zeros((t.receivers, t.width, w_hh.shape[1]), dtype=np.float32)
        for s in steps:
            new = gru_gates(gi[:, s], h, w_hh, b_hh)
            h = np.where(mask[:, s, None], new, h)
            out[:, s] = h
        outs.append(out)
    flat = np.concatenate(outs, axis=-1)[mask]
    assert len(flat) == p
    return flat
