"""Seeded maze-like map generator: static walls with bifurcations and loops, free space kept
connected.

Walls are grown as short random segments. A cell may become a block only if it is a *simple
point*: its free 8-neighbours form a single 8-connected arc around it, so removing it cannot
disconnect the free space. That keeps every free cell reachable (8-connected moves) by
construction with an O(1) test per placement; `is_connected` double-checks it once per map.
"""

from __future__ import annotations

import numpy as np

from world.config import ConfigError

# Ring of the 8 neighbours in clockwise order starting at north-west: (dy, dx).
RING = ((-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1))


def _simple_point_table() -> np.ndarray:
    """For each 8-bit pattern of free ring cells: does removing the centre keep them connected?"""
    table = np.zeros(256, dtype=bool)
    for pattern in range(256):
        free = [k for k in range(8) if pattern >> k & 1]
        if not free:
            table[pattern] = False  # an isolated free cell: never wall it in further
            continue
        seen = {free[0]}
        stack = [free[0]]
        while stack:
            k = stack.pop()
            ky, kx = RING[k]
            for j in free:
                if j not in seen:
                    jy, jx = RING[j]
                    if max(abs(jy - ky), abs(jx - kx)) == 1:
                        seen.add(j)
                        stack.append(j)
        table[pattern] = len(seen) == len(free)
    return table


SIMPLE = _simple_point_table()


def _ring_pattern(free: np.ndarray, y: int, x: int) -> int:
    h, w = free.shape
    pattern = 0
    for k, (dy, dx) in enumerate(RING):
        yy, xx = y + dy, x + dx
        if 0 <= yy < h and 0 <= xx < w and free[yy, xx]:
            pattern |= 1 << k
    return pattern


def generate_static(height: int, width: int, n_blocks: int, rng: np.random.Generator) -> np.ndarray:
    """Return a bool [H, W] array of exactly `n_blocks` static blocks; all free cells
    8-connected."""
    free = np.ones((height, width), dtype=bool)
    placed = 0
    attempts = 0
    max_attempts = 200 * max(n_blocks, 1)
    dirs = ((0, 1), (1, 0), (0, -1), (-1, 0))
    while placed < n_blocks:
        attempts += 1
        if attempts > max_attempts:  # a dense map: walls grown cell by cell (below)
            return ~_fill(free, n_blocks - placed, rng)
        y = int(rng.integers(height))
        x = int(rng.integers(width))
        dy, dx = dirs[int(rng.integers(4))]
        length = int(rng.integers(2, 7))
        turn_at = int(rng.integers(1, length + 1))
        for step in range(length):
            if placed >= n_blocks:
                break
            if not (0 <= y < height and 0 <= x < width) or not free[y, x]:
                break
            if not SIMPLE[_ring_pattern(free, y, x)]:
                break
            free[y, x] = False
            placed += 1
            if step + 1 == turn_at and rng.random() < 0.5:  # an L-bend now and then: more junctions
                dy, dx = dx, dy
            y, x = y + dy, x + dx
    return ~free


def _fill(free: np.ndarray, missing: int, rng: np.random.Generator) -> np.ndarray:
    """Block `missing` more cells of `free` (in place), each one whose loss keeps the free cells
    connected, in random order pass after pass: what a dense map needs once random wall segments
    stop fitting (only maps the segments could not finish come here: every other map is
    unchanged). A ConfigError when no free cell can be blocked without cutting the free space."""
    h, w = free.shape
    n_free = int(free.sum())
    while missing > 0:
        before = missing
        for cell in rng.permutation(h * w):
            y, x = divmod(int(cell), w)
            if not free[y, x] or missing >= n_free:  # (never the last free cell)
                continue
            free[y, x] = False  # a simple point, or one that breaks a loop (checked whole)
            if SIMPLE[_ring_pattern(free, y, x)] or is_connected(free):
                missing, n_free = missing - 1, n_free - 1
                if missing == 0:
                    break
            else:
                free[y, x] = True
        if missing == before:
            raise ConfigError(f"world config: {int((~free).sum()) + missing} static blocks do not "
                              f"fit on {h} x {w} with the free cells connected")
    return free


def is_connected(free: np.ndarray) -> bool:
    """True when every free cell of the bool [H, W] map reaches every other with 8-connected
    moves."""
    h, w = free.shape
    total = int(free.sum())
    if total == 0:
        return True
    # BFS over plain Python lists: scalar numpy indexing is ~5x slower, and this runs per map
    edge = [False] * (w + 2)
    pad = [edge] + [[False, *row, False] for row in free.tolist()] + [list(edge)]
    start = int(np.flatnonzero(free.ravel())[0])
    y0, x0 = divmod(start, w)
    pad[y0 + 1][x0 + 1] = False  # visited cells are cleared
    stack = [(y0 + 1, x0 + 1)]
    count = 1
    ring = [(int(dy), int(dx)) for dy, dx in RING]
    while stack:
        y, x = stack.pop()
        for dy, dx in ring:
            row = pad[y + dy]
            if row[x + dx]:
                row[x + dx] = False
                count += 1
                stack.append((y + dy, x + dx))
    return count == total
