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


def hash64(*words: np.ndarray | int) -> np.ndarray:
    """Broadcasting hash of integer key words to uint64."""
    with np.errstate(over="ignore"):
        h = np.uint64(0x243F6A8885A308D3)
        for w in words:
            w = np.asarray(w).astype(np.int64).astype(np.uint64)
            h = _mix(h + _GOLDEN + w)
        return np.asarray(h, dtype=np.uint64)


def uniform(seed: int, episode: np.ndarray | int, tick: np.ndarray | int, robot: np.ndarray | int,
            n: int, stream: int = 0) -> np.ndarray:
    """Uniform floats in [0, 1): shape broadcast(episode, tick, robot) + (n,).

    `stream` separates independent uses (0: action sampling, 1: tie-breaking, ...).
    """
    ep = np.asarray(episode)[..., None]
    tk = np.asarray(tick)[..., None]
    rb = np.asarray(robot)[..., None]
    k = np.arange(n)
    h = hash64(seed, stream, ep, tk, rb, k)
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)
