"""Batched shortest paths on occupancy beliefs, bit-parallel over grid rows.

A mask [R, H, W] of R independent searches is packed into bit rows [R, H, Wd] uint64 (bit
x % 64 of word x // 64), so one 8-connected wavefront step of every search is a handful of
shifts and ORs on a few thousand words: much cheaper than a [R, H, W] bool dilation, and free
of Python loops over searches. Moves follow the world's rules: 8 neighbours, a move is allowed
into any `passable` cell (no corner-cutting check, as in `world.core.step`).

Two searches are offered, both ending early once every search has what it needs:
- `steps_toward`: wavefront from a target set to each search's robot cell; returns the
  distance and which of the 9 actions start a shortest path (all of them, for tie-breaking);
- `distance_fields`: wavefront from each search's source cell; returns the [R, H, W] path
  length to every cell, encoding layer numbers in bit planes while the wavefront runs.
"""

from __future__ import annotations

import functools

import numpy as np

from world.core import ACTIONS

UNREACHED = 255  # distance of cells a `distance_fields` search did not reach
_MOVES = ACTIONS.tolist()  # the 9 moves (dy, dx) as Python ints


def pack(mask: np.ndarray) -> np.ndarray:
    """bool [..., H, W] -> uint64 bit rows [..., H, Wd], Wd = ceil(W / 64)."""
    b = np.packbits(mask, axis=-1, bitorder="little")
    nbytes = -(-mask.shape[-1] // 64) * 8
    if b.shape[-1] != nbytes:
        b = np.concatenate([b, np.zeros((*b.shape[:-1], nbytes - b.shape[-1]), np.uint8)], -1)
    return np.ascontiguousarray(b).view("<u8").astype(np.uint64, copy=False)


def unpack(bits: np.ndarray, width: int) -> np.ndarray:
    """uint64 bit rows [..., H, Wd] -> bool [..., H, width]."""
    b = np.ascontiguousarray(bits).astype("<u8", copy=False).view(np.uint8)
    return np.unpackbits(b, axis=-1, count=width, bitorder="little").view(bool)


def dilate(bits: np.ndarray) -> np.ndarray:
    """8-neighbour dilation (the cell itself included) of bit rows [..., H, Wd]."""
    h = bits | (bits << np.uint64(1)) | (bits >> np.uint64(1))
    if bits.shape[-1] > 1:  # carry bits across word boundaries
        h[..., 1:] |= bits[..., :-1] >> np.uint64(63)
        h[..., :-1] |= bits[..., 1:] << np.uint64(63)
    v = h.copy()
    v[..., 1:, :] |= h[..., :-1, :]
    v[..., :-1, :] |= h[..., 1:, :]
    return v


class Neighbourhood:
    """Gathers the 3 x 3 neighbourhood bits (in ACTIONS order) of one cell per search."""

    def __init__(self, cells: np.ndarray, height: int, width: int) -> None:
        y = cells[:, 0, None] + ACTIONS[None, :, 0]  # [R, 9]
        x = cells[:, 1, None] + ACTIONS[None, :, 1]
        self.valid = (y >= 0) & (y < height) & (x >= 0) & (x < width)
        self.rows = np.arange(len(cells))[:, None]
        self.y = np.minimum(np.maximum(y, 0), height - 1)  # (np.clip's dispatch costs more)
        xc = np.minimum(np.maximum(x, 0), width - 1)
        self.word = xc // 64
        self.shift = (xc % 64).astype(np.uint64)

    def __call__(self, bits: np.ndarray) -> np.ndarray:
        """bits [R, H, Wd] -> [R, 9] bool."""
        w = bits[self.rows, self.y, self.word]
        return ((w >> self.shift) & np.uint64(1)).astype(bool) & self.valid


def steps_toward(passable: np.ndarray, targets: np.ndarray, cells: np.ndarray,
                 max_steps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Shortest paths from each search's cell to its nearest target.

    passable, targets: bit rows [R, H, Wd] (targets outside `passable` are ignored; the robot
    cell should be passable); cells: [R, 2] (y, x). Returns dist [R] int64 (-1: no target
    reachable) and first [R, 9] bool, the actions that start a shortest path (only `stay` at
    distance 0, none when unreachable). The wavefront grows from the targets, so many targets
    cost no more than one, and stops once every robot cell is reached or nothing grows.
    """
    r, h = passable.shape[:2]
    limit = h * passable.shape[-1] * 64 if max_steps is None else max_steps
    if r == 1:  # a robot process: the same search on one Python integer
        return _steps_toward_one(passable[0], targets[0], cells[0], limit)
    nb = Neighbourhood(cells, h, passable.shape[-1] * 64)
    reached = targets & passable
    prev = nb(reached)
    dist = np.where(prev[:, 0], 0, -1)
    first = np.zeros((r, 9), dtype=bool)
    first[:, 0] = prev[:, 0]
    k = 0
    while k < limit and (dist < 0).any():
        k += 1
        grown = dilate(reached) & passable
        if np.array_equal(grown, reached):
            break
        reached = grown
        now = nb(reached)
        new = now[:, 0] & (dist < 0)
        if new.any():
            dist[new] = k
            first[new] = prev[new]
            first[new, 0] = False
        prev = now
    return dist, first


@functools.lru_cache(maxsize=8)
def _edge_masks(height: int, stride: int) -> tuple[int, int]:
    """Bits of every row but its first column, and of every row but its last column, for a
    grid of `height` rows `stride` bits apart in one integer."""
    first = sum(1 << (y * stride) for y in range(height))
    every = (1 << (height * stride)) - 1
    return every & ~first, every & ~(first << (stride - 1))


def _as_int(bits: np.ndarray) -> int:
    """Bit rows [H, Wd] uint64 -> one integer, row y's bit x at y * 64 * Wd + x."""
    return int.from_bytes(np.ascontiguousarray(bits, dtype="<u8").tobytes(), "little")


def _steps_toward_one(passable: np.ndarray, targets: np.ndarray, cell: np.ndarray,
                      limit: int) -> tuple[np.ndarray, np.ndarray]:
    """`steps_toward` for one search, its bit rows [H, Wd] as one Python integer: a wavefront
    step is a few shifts and ORs of one integer instead of a dozen numpy calls (a robot
    process decides for itself alone). Returns what `steps_toward` returns for R = 1 (tested
    equal to the batched path)."""
    h, words = passable.shape
    stride = 64 * words
    not_first, not_last = _edge_masks(h, stride)
    free = _as_int(passable)
    reached = _as_int(targets) & free
    y, x = int(cell[0]), int(cell[1])
    around = [(y + int(dy)) * stride + x + int(dx)
              if 0 <= y + dy < h and 0 <= x + dx < stride else -1 for dy, dx in _MOVES]
    here = around[0]
    first = np.zeros((1, 9), dtype=bool)
    if reached >> here & 1:
        first[0, 0] = True
        return np.zeros(1, dtype=np.int64), first
    k = 0
    while k < limit:
        k += 1
        grown = reached | (reached << 1 & not_first) | (reached >> 1 & not_last)
        grown = (grown | grown << stride | grown >> stride) & free
        if grown == reached:
            break
        if grown >> here & 1:
            first[0] = [p >= 0 and bool(reached >> p & 1) for p in around]
            return np.array([k], dtype=np.int64), first
        reached = grown
    return np.array([-1], dtype=np.int64), first


def distance_fields(passable: np.ndarray, sources: np.ndarray, width: int,
                    targets: np.ndarray | None = None, extra: int = 0,
                    max_steps: int = 254) -> np.ndarray:
    """Path length from each search's source set to every cell, uint8 [R, H, width].

    passable, sources, targets: bit rows [R, H, Wd]. Without `targets` the wavefront runs until
    nothing grows; with them, each search stops `extra` layers after it first touches one of
    its targets (cells further than that read UNREACHED, as do unreachable ones). Layer k's new
    cells are ORed into the bit planes of k's set bits, so the distance is decoded once at the
    end instead of being written per layer. One search (a robot process deciding for itself)
    runs on one Python integer, like `steps_toward`'s.
    """
    if passable.shape[0] == 1:
        return _distance_field_one(passable[0], sources[0], width,
                                   None if targets is None else targets[0], extra, max_steps)
    reached = sources & passable
    n_planes = max(1, int(max_steps).bit_length())
    planes = np.zeros((n_planes, *reached.shape), dtype=np.uint64)
    r = reached.shape[0]
    stop_at = np.full(r, max_steps, dtype=np.int64)
    if targets is not None:
        hit = (reached & targets).any(axis=(1, 2))
        stop_at[hit] = extra
    active = np.ones(r, dtype=bool)
    k = 0
    while k < max_steps:
        k += 1
        grown = dilate(reached) & passable
        if k > stop_at.min():  # freeze the searches that have gone far enough
            active = k <= stop_at
            grown = np.where(active[:, None, None], grown, reached)
        new = grown & ~reached
        if not new.any():
            break
        for b in range(n_planes):
            if k >> b & 1:
                planes[b] |= new
        reached = grown
        if targets is not None:
            hit = (new & targets).any(axis=(1, 2)) & (stop_at == max_steps)
            stop_at[hit] = k + extra
    dist = np.zeros((r, reached.shape[1], width), dtype=np.uint8)
    for b in range(n_planes):
        if planes[b].any():
            dist |= unpack(planes[b], width).astype(np.uint8) << b
    dist[~unpack(reached, width)] = UNREACHED
    return dist


def _distance_field_one(passable: np.ndarray, sources: np.ndarray, width: int,
                        targets: np.ndarray | None, extra: int, max_steps: int) -> np.ndarray:
    """`distance_fields` for one search, [1, H, width]: each layer is a few shifts and ORs of
    one integer; layer k's new cells are ORed into the integers of k's set bits, decoded once
    (tested equal to the batched path)."""
    h, words = passable.shape
    stride = 64 * words
    not_first, not_last = _edge_masks(h, stride)
    free = _as_int(passable)
    reached = _as_int(sources) & free
    goal = 0 if targets is None else _as_int(targets)
    n_planes = max(1, int(max_steps).bit_length())
    planes = [0] * n_planes
    stop_at = extra if reached & goal else max_steps
    k = 0
    while k < min(max_steps, stop_at):
        k += 1
        grown = reached | (reached << 1 & not_first) | (reached >> 1 & not_last)
        grown = (grown | grown << stride | grown >> stride) & free
        new = grown & ~reached
        if not new:
            break
        for b in range(n_planes):
            if k >> b & 1:
                planes[b] |= new
        reached = grown
        if new & goal and stop_at == max_steps:
            stop_at = k + extra
    nbytes = h * words * 8

    def rows(bits: int) -> np.ndarray:
        return unpack(np.frombuffer(bits.to_bytes(nbytes, "little"), dtype="<u8")
                      .reshape(1, h, words), width)

    dist = np.zeros((1, h, width), dtype=np.uint8)
    for b, plane in enumerate(planes):
        if plane:
            dist |= rows(plane).astype(np.uint8) << b
    dist[~rows(reached)] = UNREACHED
    return dist


def cell_bits(cells: np.ndarray, height: int, words: int) -> np.ndarray:
    """One set bit per search at cells [R, 2] (y, x): bit rows [R, height, words]."""
    bits = np.zeros((len(cells), height, words), dtype=np.uint64)
    x = cells[:, 1]
    bits[np.arange(len(cells)), cells[:, 0], x // 64] = np.uint64(1) << (x % 64).astype(np.uint64)
    return bits
