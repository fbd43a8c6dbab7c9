"""The terrain's trend under a cloud, taken off before CSF's cloth falls.

A cloth stiff enough to bridge roofs cannot bend down a slope: on steep or rolling terrain it
hangs over the ground and calls it an object (type I). Taken off a smooth surface under the
ground, the slope is gone and the cloth meets a flat terrain with the objects on it. The
surface: the lowest point of each cell of `cell_m`, empty cells from their nearest, the 10th
percentile over a square of `window_m` (objects narrower than that go), dilated back over the
same square (ridges keep their height) and averaged over it (no steps); sampled bilinearly.

Host code (scipy.ndimage), run once per cloud: `trend_at` is pure, points in, a surface out.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = ["trend_at", "TREND_PERCENTILE"]

TREND_PERCENTILE = 10   # of the lowest points over the window: a low outlier does not pull it down


def trend_at(xyz_m: np.ndarray, use: np.ndarray, *, window_m: float,
             cell_m: float) -> Callable[[np.ndarray], np.ndarray]:
    """The trend of a cloud's terrain, as a function of x, y.

    Args:
      xyz_m: float `(n, 3)` [m].
      use: bool `(n,)`: the points the surface is made of (at least one).
      window_m: objects narrower than this are not part of the trend [m].
      cell_m: the surface's cell [m] (a few points each).

    Returns:
      `height(xy)`: float `(k, 2)` [m] -> float64 `(k,)` [m], the surface sampled bilinearly
      (its edge value continued outside).
    """
    from scipy import ndimage

    xyz = np.asarray(xyz_m, np.float64)
    lo = xyz[use, :2].min(axis=0)
    ij = np.floor((xyz[use, :2] - lo) / cell_m).astype(np.int64)
    shape = (int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1)
    lowest = np.full(shape, np.inf)
    np.minimum.at(lowest, (ij[:, 1], ij[:, 0]), xyz[use, 2])
    empty = ~np.isfinite(lowest)
    if empty.any():
        nearest = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
        lowest = lowest[tuple(nearest)]
    size = max(3, 2 * math.ceil(window_m / (2 * cell_m)) + 1)
    low = ndimage.percentile_filter(lowest, TREND_PERCENTILE, size=size, mode="nearest")
    opened = ndimage.grey_dilation(low, size=(size, size), mode="nearest")
    smooth = ndimage.uniform_filter(opened, size=size, mode="nearest")

    def height(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, np.float64)
        rows = (xy[:, 1] - lo[1]) / cell_m - 0.5
        cols = (xy[:, 0] - lo[0]) / cell_m - 0.5
        return ndimage.map_coordinates(smooth, [rows, cols], order=1, mode="nearest")

    return height
