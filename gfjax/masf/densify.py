"""Multiscale TIN densification (Cao et al. 2024, Sec. 2.4, Fig. 6; SPEC 4.4). Host numpy + scipy.

1. The points of the top layer are the seeds of a 2D TIN, with simulated ground points at the
   centres of a ring of buffer cells around the grid (z of the nearest top-layer point), so
   every point lies inside the TIN and no long thin triangles form at its edge.
2. For each lower layer k, its points not yet ground whose perpendicular distance to the facet
   under them is below `DT_k = st * alpha_k + ft_m` (Eq. 2) become ground; they are all tested
   against the TIN of the previous layers, then inserted together (non-iterative per layer).
3. Finally every remaining point of the whole cloud closer than `ft_m` to the TIN is ground.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gfjax.masf.tin import GroundTin, nearest_z

__all__ = ["Densified", "buffer_cells", "densify"]


class Densified(NamedTuple):
    """Outcome of the densification.

    Attributes:
      ground: bool `(n,)` over the points given to `densify`.
      seed_ground: bool `(p,)`, potential ground points that joined the TIN in some layer.
      added_per_layer: int64 `(L,)`, potential ground points that joined at each layer (the
        top layer's seeds first).
    """

    ground: np.ndarray
    seed_ground: np.ndarray
    added_per_layer: np.ndarray


def buffer_cells(shape: tuple[int, int], *, cell_m: float) -> np.ndarray:
    """x, y of the centres of the ring of cells just outside an `(h, w)` grid, float64 `(r, 2)`."""
    h, w = shape
    cols = np.arange(-1, w + 1)
    rows_y = np.arange(0, h)
    south = np.stack([(cols + 0.5) * cell_m, np.full(len(cols), -0.5 * cell_m)], axis=1)
    north = np.stack([(cols + 0.5) * cell_m, np.full(len(cols), (h + 0.5) * cell_m)], axis=1)
    west = np.stack([np.full(h, -0.5 * cell_m), (rows_y + 0.5) * cell_m], axis=1)
    east = np.stack([np.full(h, (w + 0.5) * cell_m), (rows_y + 0.5) * cell_m], axis=1)
    return np.concatenate([south, north, west, east])


def densify(points_m: np.ndarray, seeds: np.ndarray, layers: np.ndarray, alphas_m: np.ndarray, *,
            shape: tuple[int, int], cell_m: float, st: float, ft_m: float) -> Densified:
    """Label ground points by top-down densification of the layer TINs.

    Args:
      points_m: float64 `(n, 3)` local metres, every point the filter uses.
      seeds: int64 `(p,)` indices into `points_m` of the potential ground points.
      layers: bool `(L, p)`, layer membership of the potential ground points, top layer first.
      alphas_m: float64 `(L,)` the layers' alpha [m].
      shape: `(h, w)` of the preprocessing grid; cell_m its cell [m].
      st: slope threshold ST [-]; ft_m: final threshold FT [m] (Eq. 2).
    """
    n_layers, n_seeds = layers.shape
    seed_xyz = points_m[seeds]
    in_tin = layers[0].copy() if n_layers else np.zeros(n_seeds, dtype=bool)
    if not in_tin.any():
        in_tin[:] = True          # no top layer (degenerate input): every seed is a seed
    added = np.zeros(max(n_layers, 1), dtype=np.int64)
    added[0] = np.count_nonzero(in_tin)
    ring_xy = buffer_cells(shape, cell_m=cell_m)
    ring = np.column_stack([ring_xy, nearest_z(ring_xy, seed_xyz[in_tin])])
    tin, tin_size = None, -1
    for level in range(1, n_layers):
        candidates = np.flatnonzero(layers[level] & ~in_tin)
        if len(candidates) == 0:
            continue
        size = int(np.count_nonzero(in_tin))
        if tin is None or size != tin_size:
            tin, tin_size = GroundTin(np.concatenate([seed_xyz[in_tin], ring])), size
        threshold_m = st * alphas_m[level] + ft_m
        accepted = candidates[tin.distance_m(seed_xyz[candidates]) < threshold_m]
        in_tin[accepted] = True
        added[level] = len(accepted)
    ground = np.zeros(len(points_m), dtype=bool)
    ground[seeds[in_tin]] = True
    rest = np.flatnonzero(~ground)
    if len(rest):
        if tin is None or int(np.count_nonzero(in_tin)) != tin_size:
            tin = GroundTin(np.concatenate([seed_xyz[in_tin], ring]))
        ground[rest[tin.distance_m(points_m[rest]) < ft_m]] = True
    return Densified(ground, in_tin, added)
