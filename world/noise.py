"""Counter-based random numbers keyed by (seed, episode, tick, robot, k).

A robot process and the batched evaluator draw the very same numbers for the same key without
sharing any generator state, which is what makes sampled decisions identical on the swarm and
in-process. The mixer is splitmix64's finaliser over a running combination of the key words.
"""

from __future__ import annotations

import numpy as np

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _mix(z: np.ndarray) -> np.ndarray:
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


_MASK = (1 << 64) - 1
_H0 = 0x243F6A8885A308D3


def _mix_int(z: int) -> int:
    """`_mix` of one word in Python integers (exact modulo 2**64)."""
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK
    return z ^ (z >> 31)


def hash64(*words: np.ndarray | int) -> np.ndarray:
    """Broadcasting hash of integer key words to uint64.

    Leading scalar words are folded in Python integers (the same arithmetic modulo 2**64): a
    robot's key is mostly scalars, and a numpy scalar operation costs a microsecond each."""
    h, rest = _H0, list(words)
    while rest and isinstance(rest[0], (int, np.integer)):
        h = _mix_int((h + int(_GOLDEN) + (int(rest.pop(0)) & _MASK)) & _MASK)
    if not rest:
        return np.asarray(h, dtype=np.uint64)
    with np.errstate(over="ignore"):
        hv = np.uint64(h)
        for w in rest:
            w = np.asarray(w).astype(np.int64).astype(np.uint64)
            hv = _mix(hv + _GOLDEN + w)
        return np.asarray(hv, dtype=np.uint64)


def uniform(seed: int, episode: np.ndarray | int, tick: np.ndarray | int, robot: np.ndarray | int,
            n: int, stream: int = 0) -> np.ndarray:
    """Uniform floats in [0, 1): shape broadcast(episode, tick, robot) + (n,).

    `stream` separates independent uses (0: action sampling, 1: tie-breaking, ...).
    """
    ep, tk, rb = np.asarray(episode), np.asarray(tick), np.asarray(robot)
    k = np.arange(n)
    if ep.size == 1 and tk.size == 1 and rb.size == 1:  # one key (a robot): scalars but k
        shape = np.broadcast_shapes(ep.shape, tk.shape, rb.shape) + (n,)
        h = hash64(seed, stream, int(ep.reshape(-1)[0]), int(tk.reshape(-1)[0]),
                   int(rb.reshape(-1)[0]), k).reshape(shape)
    else:
        h = hash64(seed, stream, ep[..., None], tk[..., None], rb[..., None], k)
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)
