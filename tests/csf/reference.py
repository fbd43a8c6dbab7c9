"""A literal, sequential Python transcription of `cloth-simulation-filter` 1.1.7 (C++ sources
Cloth.cpp, Particle.cpp, CSF.cpp `do_cloth`), for small test grids: the reference the JAX
solver is measured against (it is slow: pure Python loops, 16 springs per particle per step).
"""
from __future__ import annotations

import numpy as np

from gfjax.csf.config import (DAMPING, GRAVITY, STOP_DISPLACEMENT_M, double_move, single_move)


def neighbour_lists(h: int, w: int) -> list[list[int]]:
    """Each particle's springs in the order Cloth.cpp's constructor appends them."""
    nbrs: list[list[int]] = [[] for _ in range(h * w)]

    def tie(a: int, b: int) -> None:
        nbrs[a].append(b)
        nbrs[b].append(a)

    def at(i: int, j: int) -> int:
        return j * w + i

    for step in (1, 2):
        for i in range(w):
            for j in range(h):
                if i < w - step:
                    tie(at(i, j), at(i + step, j))
                if j < h - step:
                    tie(at(i, j), at(i, j + step))
                if i < w - step and j < h - step:
                    tie(at(i, j), at(i + step, j + step))
                    tie(at(i + step, j), at(i, j + step))
    return nbrs


def simulate(heights: np.ndarray, start_u: float, *, time_step: float = 0.65, rigidness: int = 3,
             iterations: int = 500) -> tuple[np.ndarray, np.ndarray, int]:
    """The package's cloth loop on a `[j, i]` surface (inverted frame), sequentially.

    Returns:
      `(u, movable, steps)`: final heights `(h, w)`, bool `(h, w)`, steps run.
    """
    h, w = heights.shape
    n = h * w
    hv = [float(v) for v in heights.reshape(-1)]
    nbrs = neighbour_lists(h, w)
    pos = [float(start_u)] * n
    old = [float(start_u)] * n
    mov = [True] * n
    accel = -GRAVITY * time_step ** 4
    both, single = double_move(rigidness), single_move(rigidness)
    steps = 0
    for _ in range(iterations):
        steps += 1
        before = list(pos)
        for p in range(n):
            if mov[p]:
                temp = pos[p]
                pos[p] = pos[p] + (pos[p] - old[p]) * (1.0 - DAMPING) + accel
                old[p] = temp
        for p in range(n):
            for q in nbrs[p]:
                gap = pos[q] - pos[p]
                if mov[p] and mov[q]:
                    pos[p] += gap * both
                    pos[q] -= gap * both
                elif mov[p]:
                    pos[p] += gap * single
                elif mov[q]:
                    pos[q] -= gap * single
        max_diff = 0.0
        for p in range(n):
            if mov[p]:
                max_diff = max(max_diff, abs(old[p] - pos[p]))
        del before
        for p in range(n):
            if pos[p] < hv[p]:
                if mov[p]:
                    pos[p] = hv[p]
                mov[p] = False
        if max_diff != 0 and max_diff < STOP_DISPLACEMENT_M:
            break
    return np.asarray(pos).reshape(h, w), np.asarray(mov).reshape(h, w), steps
