"""A literal, sequential Python transcription of `cloth-simulation-filter` 1.1.7 (C++ sources
Cloth.cpp, Particle.cpp, CSF.cpp `do_cloth`), for small test grids: the reference the JAX
solver is measured against (it is slow: pure Python loops, 16 springs per particle per step).
"""
from __future__ import annotations

import numpy as np

from gfjax.csf.config import DAMPING, GRAVITY, STOP_DISPLACEMENT_M, double_move, single_move


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


def particle_heights(xy: np.ndarray, u: np.ndarray, shape: tuple[int, int], cell_m: float) -> np.ndarray:
    """Rasterization.cpp `RasterTerrian`, first part: nearest point's `u` per particle (NaN if
    none); ties go to the lowest point (largest `u`), as gfjax documents."""
    h, w = shape
    out = np.full((h, w), np.nan)
    best = np.full((h, w), np.inf)
    for (x, y), z in zip(xy.astype(np.float64), u.astype(np.float64)):
        col, row = int(np.floor(x / cell_m + 0.5)), int(np.floor(y / cell_m + 0.5))
        d2 = (x - col * cell_m) ** 2 + (y - row * cell_m) ** 2
        if d2 < best[row, col] or (d2 == best[row, col] and z > out[row, col]):
            best[row, col], out[row, col] = d2, z
    return out


def scanline_fill(heights: np.ndarray) -> np.ndarray:
    """`findHeightValByScanline`: east, west, south (-j), north along the particle's own row and
    column; then (instead of the package's neighbour BFS) the same scan over the filled grid."""
    def one(z: np.ndarray) -> np.ndarray:
        h, w = z.shape
        out = z.copy()
        for j in range(h):
            for i in range(w):
                if not np.isnan(z[j, i]):
                    continue
                for cand in ([z[j, k] for k in range(i + 1, w)] + [z[j, k] for k in range(i - 1, -1, -1)]
                             + [z[k, i] for k in range(j - 1, -1, -1)] + [z[k, i] for k in range(j + 1, h)]):
                    if not np.isnan(cand):
                        out[j, i] = cand
                        break
        return out
    return one(one(heights))


def smooth_slopes(u: np.ndarray, movable: np.ndarray, heights: np.ndarray, *, smooth_m: float = 0.3,
                  min_size: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """Cloth.cpp `movableFilter`, `findUnmovablePoint`, `handle_slop_connected`, literally
    (breadth-first component search, seeds, breadth-first growth)."""
    from collections import deque
    h, w = u.shape
    u, mov = u.copy(), movable.copy()
    visited = np.zeros((h, w), bool)
    for i in range(w):
        for j in range(h):
            if not mov[j, i] or visited[j, i]:
                continue
            connected, neighbours, pos = [(j, i)], [], {(j, i): 0}
            visited[j, i] = True
            queue = deque([(j, i)])
            while queue:
                cj, ci = queue.popleft()
                nb = []
                for dj, di in ((0, -1), (0, 1), (-1, 0), (1, 0)):
                    nj, ni = cj + dj, ci + di
                    if 0 <= nj < h and 0 <= ni < w and mov[nj, ni]:
                        if not visited[nj, ni]:
                            visited[nj, ni] = True
                            pos[(nj, ni)] = len(connected)
                            connected.append((nj, ni))
                            queue.append((nj, ni))
                        nb.append(pos[(nj, ni)])
                neighbours.append(nb)
            if len(connected) <= min_size:
                continue
            edge = []
            for k, (cj, ci) in enumerate(connected):
                for dj, di in ((0, -1), (0, 1), (-1, 0), (1, 0)):
                    nj, ni = cj + dj, ci + di
                    if (0 <= nj < h and 0 <= ni < w and not mov[nj, ni]
                            and abs(heights[cj, ci] - heights[nj, ni]) < smooth_m):
                        u[cj, ci], mov[cj, ci] = heights[cj, ci], False
                        edge.append(k)
                        break
            seen = np.zeros(len(connected), bool)
            seen[edge] = True
            queue = deque(edge)
            while queue:
                k = queue.popleft()
                cj, ci = connected[k]
                for m in neighbours[k]:
                    nj, ni = connected[m]
                    if abs(heights[cj, ci] - heights[nj, ni]) < smooth_m:
                        if mov[nj, ni]:
                            u[nj, ni], mov[nj, ni] = heights[nj, ni], False
                        if not seen[m]:
                            seen[m] = True
                            queue.append(m)
    return u, mov


def height_above_cloth(xy: np.ndarray, u: np.ndarray, cloth_u: np.ndarray, cell_m: float) -> np.ndarray:
    """c2cdist.cpp: bilinear cloth height minus the point's `u`."""
    out = np.empty(len(u))
    for k, ((x, y), z) in enumerate(zip(xy.astype(np.float64), u.astype(np.float64))):
        col, row = int(x / cell_m), int(y / cell_m)
        fx, fy = x / cell_m - col, y / cell_m - row
        c = cloth_u.astype(np.float64)
        out[k] = (c[row, col] * (1 - fx) * (1 - fy) + c[row + 1, col] * (1 - fx) * fy
                  + c[row + 1, col + 1] * fx * fy + c[row, col + 1] * fx * (1 - fy)) - z
    return out


def sweep(u: np.ndarray, movable: np.ndarray, *, rigidness: int = 3) -> np.ndarray:
    """One pass of `satisfyConstraintSelf` over all particles in `j * w + i` order."""
    h, w = u.shape
    nbrs = neighbour_lists(h, w)
    pos = [float(v) for v in u.reshape(-1)]
    mov = [bool(m) for m in movable.reshape(-1)]
    both, single = double_move(rigidness), single_move(rigidness)
    for p in range(h * w):
        for q in nbrs[p]:
            gap = pos[q] - pos[p]
            if mov[p] and mov[q]:
                pos[p] += gap * both
                pos[q] -= gap * both
            elif mov[p]:
                pos[p] += gap * single
            elif mov[q]:
                pos[q] -= gap * single
    return np.asarray(pos).reshape(h, w)
