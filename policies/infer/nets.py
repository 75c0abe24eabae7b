"""The four learned networks in numpy for inference (robots and the batched evaluator); the torch
modules in policies/ (commattn.py, commnet.py, bicnet.py, vain.py) are their trainable twins,
with the same configs, weight names and shapes, checked against these by tests on every layer.

Each class is built from a config and a {name: array} weight dict; `shapes` gives the weight
shapes a config implies (what a checkpoint or a weights message must carry).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from policies.infer.layers import (
    Weights,
    bigru,
    embedding,
    gru_cell,
    linear,
    pack_bigru,
    relu,
    softmax,
    token_embed,
)
from policies.infer.tokens import ModelConfig, Tokens
from world.core import N_ACTIONS

NO_ACTION = N_ACTIONS  # action-embedding index used where there is no predecessor
Shapes = dict[str, tuple[int, ...]]


def _linear(name: str, n_in: int, n_out: int, bias: bool = True) -> Shapes:
    out: Shapes = {f"{name}.weight": (n_out, n_in)}
    if bias:
        out[f"{name}.bias"] = (n_out,)
    return out


def _embed(name: str, member: int, pair: int, out: int, own: int) -> Shapes:
    s = {**_linear(f"{name}.member", member, out), **_linear(f"{name}.pair", pair, out, False)}
    return {**s, **_linear(f"{name}.own", own, out, False)} if own else s


def _gru(name: str, n_in: int, hidden: int, cell: bool = False) -> Shapes:
    suffixes = [""] if cell else ["_l0", "_l0_reverse"]
    out: Shapes = {}
    for sfx in suffixes:
        out.update({f"{name}.weight_ih{sfx}": (3 * hidden, n_in),
                    f"{name}.weight_hh{sfx}": (3 * hidden, hidden),
                    f"{name}.bias_ih{sfx}": (3 * hidden,), f"{name}.bias_hh{sfx}": (3 * hidden,)})
    return out


def _mlp(name: str, n_in: int, hidden: int, n_out: int) -> Shapes:
    return {**_linear(f"{name}.0", n_in, hidden), **_linear(f"{name}.2", hidden, n_out)}


def mlp(w: Weights, name: str, x: np.ndarray) -> np.ndarray:
    """nn.Sequential(Linear, ReLU, Linear) `name`."""
    return linear(w, f"{name}.2", relu(linear(w, f"{name}.0", x)))


class NumpyNet:
    """Base of the numpy networks: the weights and the config."""

    chained = False

    def __init__(self, cfg: ModelConfig, weights: Weights, keep: bool = False) -> None:
        self.cfg, self.w = cfg, weights
        # keep arrays derived from the weights between calls: only for an owner that changes
        # the weights through `load_weights`, which calls `forget` (not a LearnedPolicy, whose
        # weights are views of torch parameters an optimizer moves)
        self.keep = keep
        self._derived: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def forget(self) -> None:
        """Drop the arrays derived from the weights (they changed)."""
        self._derived.clear()

    def packed_bigru(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """`pack_bigru(self.w, name)`, built once while the weights stay (`keep`)."""
        if not self.keep:
            return pack_bigru(self.w, name)
        out = self._derived.get(name)
        if out is None:
            out = self._derived[name] = pack_bigru(self.w, name)
        return out

    @staticmethod
    def shapes(cfg: ModelConfig, member: int, pair: int, own: int) -> Shapes:
        raise NotImplementedError

    def forward(self, t: Tokens) -> tuple[np.ndarray, np.ndarray]:
        """Tokens -> logits [R, 9], value [R] (unchained networks)."""
        raise NotImplementedError


# --------------------------------------------------------------------------- CommAttn
@dataclass
class CommAttnConfig(ModelConfig):
    """Sizes of the CommAttn network."""

    embed: int = 32
    """Width of the per-member token embedding fed to the BiGRU."""
    hidden: int = 32
    """BiGRU hidden size per direction; h_j has 2 * hidden values."""
    state: int = 64
    """Decoder state size (the hidden-state message carries this many floats)."""
    match: int = 32
    """Hidden width of the matching net m(s, h)."""
    action_embed: int = 16
    """Width of the predecessor-action embedding."""
    self_input: bool = True
    """Also feed the receiver's own encoder state h_i and token embedding x_i to the action and
    value heads g and b (the paper's decoder reaches them only through attention; False
    reproduces it exactly). With it, reacting to the own patch need not wait for attention to
    learn to find oneself (3x faster early learning in pilots)."""


def hint_prior(cfg: ModelConfig, own: Any) -> Any:
    """The logit prior [R, 9] of model field `hint_prior`: that many on each receiver's hinted
    move (the own features' last 9 columns, one-hot), or None (no hint, or a prior of 0).
    Numpy or torch, as `own` is."""
    if not (getattr(cfg, "hint", False) and getattr(cfg, "hint_prior", 0.0)) or own is None:
        return None
    return own[:, -N_ACTIONS:] * float(cfg.hint_prior)  # (float32 stays float32)


@dataclass
class Encoded:
    """Encoder output of R receivers over their members (numpy)."""

    h: np.ndarray  # [R, M, 2H]
    keys: np.ndarray  # [R, M, K] W_h h_j + b, precomputed for the matching net
    mask: np.ndarray  # [R, M] bool
    mine: np.ndarray  # [R, 2H (+E)] the receiver's own h_i (and token embedding x_i)
    prior: np.ndarray | None = None  # [R, 9] added to the logits (model hint_prior), or None

    def rows(self, lo: int, hi: int) -> Encoded:
        return Encoded(self.h[lo:hi], self.keys[lo:hi], self.mask[lo:hi], self.mine[lo:hi],
                       None if self.prior is None else self.prior[lo:hi])


@dataclass
class Step:
    """One decoder step of R receivers."""

    logits: np.ndarray  # [R, 9]
    value: np.ndarray  # [R]
    state: np.ndarray  # [R, S]
    context: np.ndarray  # [R, 2H]
    alpha: np.ndarray  # [R, M] attention weights (0 on padding)


class NumpyCommAttn(NumpyNet):
    """policies.commattn.CommAttn: BiGRU encoder, attention, GRU decoder chained over ids."""

    chained = True
    cfg: CommAttnConfig

    @staticmethod
    def shapes(cfg: CommAttnConfig, member: int, pair: int, own: int) -> Shapes:  # type: ignore[override]
        e, h, s, k, a = cfg.embed, cfg.hidden, cfg.state, cfg.match, cfg.action_embed
        mine = 2 * h + e if cfg.self_input else 0
        return {"s0": (s,), **_embed("embed", member, pair, e, own), **_gru("gru", e, h),
                "action.weight": (N_ACTIONS + 1, a), **_linear("match_s", s, k, False),
                **_linear("match_h", 2 * h, k), **_linear("match_v", k, 1, False),
                **_gru("cell", a + 2 * h, s, cell=True),
                **_mlp("policy", a + s + 2 * h + mine, s, N_ACTIONS),
                **_mlp("value", s + 2 * h + mine, s, 1)}

    def encode(self, t: Tokens) -> Encoded:
        w = self.w
        x = token_embed(w, "embed", t)
        flat = bigru(w, "gru", x, t, self.packed_bigru("gru"))
        mine = flat[t.own_row]
        if self.cfg.self_input:  # also the receiver's own token embedding (a skip past the BiGRU)
            mine = np.concatenate([mine, x[t.own_row]], axis=-1)
        h, mask = t.padded(flat)
        keys, _ = t.padded(linear(w, "match_h", flat))
        return Encoded(h=h, keys=keys, mask=mask, mine=mine,
                       prior=hint_prior(self.cfg, t.own_feats))

    def decode(self, enc: Encoded, s_prev: np.ndarray, a_prev: np.ndarray,
               value: bool = True) -> Step:
        """One decoder step given the predecessors' (s_{p(i)}, a_{p(i)}); without `value` the
        baseline head is skipped (zeros: a robot acting needs no baseline, and the decode is
        on the chain's critical path)."""
        w = self.w
        keys = np.tanh(enc.keys + linear(w, "match_s", s_prev)[:, None])
        energy = linear(w, "match_v", keys)[..., 0]
        alpha = softmax(energy, axis=1, finite=True) if enc.mask.all() else \
            softmax(np.where(enc.mask, energy, -np.inf), axis=1)
        context = (alpha[:, None, :] @ enc.h)[:, 0]
        emb = embedding(w, "action", a_prev)
        own = [enc.mine] if self.cfg.self_input else []
        state = gru_cell(w, "cell", np.concatenate([emb, context], axis=-1), s_prev)
        logits = mlp(w, "policy", np.concatenate([emb, state, context, *own], axis=-1))
        if enc.prior is not None:
            logits = logits + enc.prior
        b = mlp(w, "value", np.concatenate([state, context, *own], axis=-1))[:, 0] if value else \
            np.zeros(len(state), dtype=np.float32)
        return Step(logits, b, state, context, alpha)

    def chain(self, enc: Encoded, robot: np.ndarray, pred: np.ndarray,
              choose: Callable[[slice, np.ndarray], np.ndarray]) -> tuple[Step, np.ndarray]:
        """Decode every receiver in id order (rows id-major); receiver r takes the state and
        action of row `pred[r]` (-1: none, s_0 and the no-action token). `choose(rows, logits)`
        picks the actions of a block of rows. Returns the outputs and actions in row order."""
        if len(robot) and (np.diff(robot) < 0).any():
            raise ValueError("chain needs receivers in id-major order")
        r, s = len(robot), self.cfg.state
        state = np.zeros((r, s), dtype=np.float32)
        actions = np.zeros(r, dtype=np.int64)
        steps: list[Step] = []
        lo = 0
        for size in (np.bincount(robot).tolist() if r else []):
            if size == 0:
                continue
            hi = lo + size
            pr = pred[lo:hi]
            has = pr >= 0
            at = np.clip(pr, 0, max(lo - 1, 0))
            s_prev = np.where(has[:, None], state[at], self.w["s0"][None, :]).astype(np.float32)
            a_prev = np.where(has, actions[at], NO_ACTION)
            out = self.decode(enc.rows(lo, hi), s_prev, a_prev)
            state[lo:hi] = out.state
            actions[lo:hi] = choose(slice(lo, hi), out.logits)
            steps.append(out)
            lo = hi
        if not steps:
            z = np.zeros
            return Step(z((0, N_ACTIONS), np.float32), z(0, np.float32), state,
                        z((0, enc.h.shape[2]), np.float32),
                        z((0, enc.h.shape[1]), np.float32)), actions
        width = enc.h.shape[1]
        alpha = np.concatenate([np.pad(o.alpha, ((0, 0), (0, width - o.alpha.shape[1])))
                                for o in steps])
        return Step(np.concatenate([o.logits for o in steps]),
                    np.concatenate([o.value for o in steps]), state,
                    np.concatenate([o.context for o in steps]), alpha), actions


# --------------------------------------------------------------------------- CommNet
@dataclass
class CommNetConfig(ModelConfig):
    """Sizes of the CommNet network."""

    hidden: int = 64
    """Hidden size of every agent's state h_j."""
    steps: int = 2
    """Communication steps K."""


class NumpyCommNet(NumpyNet):
    """policies.commnet.CommNet: K steps of mean pooling over the receiver's neighbourhood."""

    cfg: CommNetConfig

    @staticmethod
    def shapes(cfg: CommNetConfig, member: int, pair: int, own: int) -> Shapes:  # type: ignore[override]
        h = cfg.hidden
        out = _embed("encoder", member, pair, h, own)
        for k in range(cfg.steps):
            out.update(_linear(f"own.{k}", h, h))
        for k in range(cfg.steps):
            out.update(_linear(f"comm.{k}", h, h, False))
        return {**out, **_mlp("policy", h, h, N_ACTIONS), **_mlp("value", h, h, 1)}

    def forward(self, t: Tokens) -> tuple[np.ndarray, np.ndarray]:
        w = self.w
        h0, mask = t.padded(token_embed(w, "encoder", t))
        m = mask[..., None].astype(np.float32)
        others = np.maximum(t.lens - 1, 1).astype(np.float32)[:, None, None]
        h = h0
        for k in range(self.cfg.steps):
            c = ((h.sum(1, keepdims=True) - h) / others) * m
            h = np.tanh(linear(w, f"own.{k}", h) + linear(w, f"comm.{k}", c) + h0) * m
        mine = h[np.arange(h.shape[0]), t.self_pos]
        return mlp(w, "policy", mine), mlp(w, "value", mine)[:, 0]


# --------------------------------------------------------------------------- BicNet
@dataclass
class BicNetConfig(ModelConfig):
    """Sizes of the BicNet network."""

    embed: int = 32
    """Width of the per-member token embedding fed to the BiGRU."""
    hidden: int = 32
    """BiGRU hidden size per direction."""


class NumpyBicNet(NumpyNet):
    """policies.bicnet.BicNet: a BiGRU over the members; heads on the receiver's own output."""

    cfg: BicNetConfig

    @staticmethod
    def shapes(cfg: BicNetConfig, member: int, pair: int, own: int) -> Shapes:  # type: ignore[override]
        e, h = cfg.embed, cfg.hidden
        return {**_embed("embed", member, pair, e, own), **_gru("gru", e, h),
                **_mlp("policy", 2 * h, 2 * h, N_ACTIONS), **_mlp("value", 2 * h, 2 * h, 1)}

    def forward(self, t: Tokens) -> tuple[np.ndarray, np.ndarray]:
        w = self.w
        mine = bigru(w, "gru", token_embed(w, "embed", t), t, self.packed_bigru("gru"))[t.own_row]
        return mlp(w, "policy", mine), mlp(w, "value", mine)[:, 0]


# --------------------------------------------------------------------------- VAIN
@dataclass
class VAINConfig(ModelConfig):
    """Sizes of the VAIN network."""

    hidden: int = 64
    """Width of the member embedding e_j and of the decoder."""
    attention: int = 16
    """Length of the attention vector a_j."""


class NumpyVAIN(NumpyNet):
    """policies.vain.VAIN: kernel attention exp(-||a_i - a_j||^2) over the other members."""

    cfg: VAINConfig

    @staticmethod
    def shapes(cfg: VAINConfig, member: int, pair: int, own: int) -> Shapes:  # type: ignore[override]
        h = cfg.hidden
        return {**_linear("encoder.0", h, h), **_embed("embed", member, pair, h, own),
                **_linear("attend", h, cfg.attention), **_linear("decoder.0", 2 * h, h),
                **_linear("policy", h, N_ACTIONS), **_linear("value", h, 1)}

    def forward(self, t: Tokens) -> tuple[np.ndarray, np.ndarray]:
        w = self.w
        e, mask = t.padded(relu(linear(w, "encoder.0", token_embed(w, "embed", t))))
        rows = np.arange(e.shape[0])
        a = linear(w, "attend", e)
        e_i, a_i = e[rows, t.self_pos], a[rows, t.self_pos]
        d2 = ((a - a_i[:, None, :]) ** 2).sum(-1)
        others = mask.copy()
        others[rows, t.self_pos] = False
        wt = softmax(np.where(others, -d2, np.float32(-1e9)), axis=1) * others  # alone: none
        comm = (wt[..., None] * e).sum(1)
        z = relu(linear(w, "decoder.0", np.concatenate([e_i, comm], axis=-1)))
        return linear(w, "policy", z), linear(w, "value", z)[:, 0]


NETS: dict[str, tuple[type[ModelConfig], type[NumpyNet]]] = {
    "commattn": (CommAttnConfig, NumpyCommAttn),
    "commnet": (CommNetConfig, NumpyCommNet),
    "bicnet": (BicNetConfig, NumpyBicNet),
    "vain": (VAINConfig, NumpyVAIN),
}
