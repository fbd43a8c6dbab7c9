"""A guard against ground spikes: ground points far above or below the ground around them.

A filter that keeps a chimney top, a wire or a multipath return far below the terrain as ground
puts a spike in the DTM: one cell metres off, which a surveyor sees at once and a flood model
follows. Such a point stands alone among the ground points around it, so it is told by them:
with its `k` nearest ground neighbours (in x, y), a point whose height differs from their
median by more than `threshold_m + slope * d` (`d`: the median distance to them, so a slope of
`slope` between them and the point is tolerated) is no ground. Larger wrongly kept objects
(a whole roof) are a filter's own business: this only removes what no ground surface can hold.

Host code (scipy's cKDTree), run once on a method's labels; `despike` is pure: labels in, labels
out.
"""
from __future__ import annotations

import numpy as np

__all__ = ["despike", "NEIGHBOURS", "THRESHOLD_M", "SLOPE"]

# Chosen on the training files with the labels of SMRF, DMF and MASF (the most files passing
# over the three; ties: the lowest ISPRS total error of SMRF): 8 neighbours, 1 m, slope 0.5.
NEIGHBOURS = 8           # ground neighbours a point is compared with
THRESHOLD_M = 1.0        # height off their median tolerated next to them [m]
SLOPE = 0.5              # ... plus this rise over run, over the median distance to them


def _median_rows(a: np.ndarray) -> np.ndarray:
    """`np.median(a, axis=1)` of a float `(m, k)` array, by one partition (no sort)."""
    k = a.shape[1]
    middle = [(k - 1) // 2, k // 2]
    part = np.partition(a, middle, axis=1)
    return 0.5 * (part[:, middle[0]] + part[:, middle[1]])


def despike(xyz_m: np.ndarray, ground: np.ndarray, *, threshold_m: float = THRESHOLD_M, slope: float = SLOPE,
            k: int = NEIGHBOURS) -> np.ndarray:
    """Ground labels without the spikes (see the module docstring).

    Args:
      xyz_m: coordinates, float `(n, 3)` [m].
      ground: bool `(n,)`, a filter's labels.
      threshold_m: height off the neighbours' median tolerated next to them [m].
      slope: rise over run tolerated on top, over the median distance to them [-].
      k: neighbours compared with.

    Returns:
      bool `(n,)`: `ground` with the spikes False. With `k` or fewer ground points, `ground`.
    """
    from scipy.spatial import cKDTree

    ground = np.asarray(ground, dtype=bool)
    index = np.flatnonzero(ground)
    if index.size <= k:
        return ground.copy()
    xyz = np.asarray(xyz_m, dtype=np.float64)[index]
    xy = xyz[:, :2] - xyz[:, :2].min(axis=0)
    distance, neighbour = cKDTree(xy).query(xy, k=k + 1, workers=-1)
    distance, neighbour = distance[:, 1:], neighbour[:, 1:]              # the point itself first
    off = xyz[:, 2] - _median_rows(xyz[neighbour, 2])
    allowed = threshold_m + slope * _median_rows(distance)
    out = ground.copy()
    out[index[np.abs(off) > allowed]] = False
    return out
