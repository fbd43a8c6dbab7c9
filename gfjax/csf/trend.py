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

__all__ = ["trend_at", "reach_m", "TREND_PERCENTILE"]

TREND_PERCENTILE = 10   # of the lowest points over the window: a low outlier does not pull it down


def _side(window_m: float, cell_m: float) -> int:
    """The side of the squares the surface is filtered over [cells]: odd, at least 3."""
    return max(3, 2 * math.ceil(window_m / (2 * cell_m)) + 1)


def reach_m(window_m: float, cell_m: float) -> float:
    """How far from a point the trend there reads the cloud [m] (`trend_at`'s arguments): the
    percentile, the dilation and the mean each reach half a square out, the point's own cell
    and the next one that the bilinear sampling reads one more each (an empty cell's nearest
    point, further, aside). A window of the cloud that holds this much around a point has the
    whole cloud's trend there."""
    return (3 * (_side(window_m, cell_m) // 2) + 2) * cell_m


def trend_at(xyz_m: np.ndarray, use: np.ndarray, *, window_m: float, cell_m: float,
             corner_m: np.ndarray | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """The trend of a cloud's terrain, as a function of x, y.

    Args:
      xyz_m: float `(n, 3)` [m].
      use: bool `(n,)`: the points the surface is made of (at least one).
      window_m: objects narrower than this are not part of the trend [m].
      cell_m: the surface's cell [m] (a few points each).
      corner_m: float `(2,)` x, y of the surface's first cell [m], at or below the points' own
        (a survey's window lays it on the survey's lattice: `gfjax.io.cloud.Frame.snap`); None:
        the points' own lowest x, y.

    Returns:
      `height(xy)`: float `(k, 2)` [m] -> float64 `(k,)` [m], the surface sampled bilinearly
      (its edge value continued outside).
    """
    from scipy import ndimage

    xyz = np.asarray(xyz_m, np.float64)
    lo = xyz[use, :2].min(axis=0) if corner_m is None else np.asarray(corner_m, np.float64)
    ij = np.floor((xyz[use, :2] - lo) / cell_m).astype(np.int64)
    shape = (int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1)
    lowest = np.full(shape, np.inf)
    np.minimum.at(lowest, (ij[:, 1], ij[:, 0]), xyz[use, 2])
    empty = ~np.isfinite(lowest)
    if empty.any():
        nearest = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
        lowest = lowest[tuple(nearest)]
    size = _side(window_m, cell_m)
    low = ndimage.percentile_filter(lowest, TREND_PERCENTILE, size=size, mode="nearest")
    opened = ndimage.grey_dilation(low, size=(size, size), mode="nearest")
    smooth = ndimage.uniform_filter(opened, size=size, mode="nearest")

    def height(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, np.float64)
        rows = (xy[:, 1] - lo[1]) / cell_m - 0.5
        cols = (xy[:, 0] - lo[0]) / cell_m - 0.5
        return ndimage.map_coordinates(smooth, [rows, cols], order=1, mode="nearest")

    return height
