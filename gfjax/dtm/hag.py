"""Height above ground: each point's height over a TIN of the ground points.

The habit of PDAL's `filters.hag_delaunay` (dimension `HeightAboveGround`), lidR's
`normalize_height(tin())` and LAStools' `lasheight`: the ground points are triangulated in x, y
(scipy's Delaunay, as the DTM's fill is), a point's ground is the linear interpolation of the
triangle under it, and outside the triangles' hull the height of its nearest ground point. A
ground point is a vertex of the TIN, so its height above ground is 0 (but for ground points
stacked at one x, y: the TIN keeps one of them, the others stand off it by their difference).
"""
from __future__ import annotations

import numpy as np

__all__ = ["height_above_ground", "DIMENSION", "DESCRIPTION"]

DIMENSION = "HeightAboveGround"          # PDAL's name; stored as float64, as PDAL's `double`
DESCRIPTION = "height above ground"


def height_above_ground(xyz: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """Heights above the ground TIN, float64 `(n,)`, in the units of `xyz`.

    Args:
      xyz: float `(n, 3)`, one unit on all axes or z in its own (heights come in z's unit).
      ground: bool `(n,)`, at least one True.

    Raises:
      ValueError: no ground point.
    """
    import scipy.spatial
    from scipy.interpolate import LinearNDInterpolator

    xyz = np.asarray(xyz, np.float64)
    ground = np.asarray(ground, bool)
    if not ground.any():
        raise ValueError("no ground point to measure heights from")
    base = xyz[ground]
    origin = base[:, :2].min(axis=0)                 # Qhull in local coordinates: no lost digits
    xy = xyz[:, :2] - origin
    surface = np.full(len(xyz), np.nan)
    try:
        tin = scipy.spatial.Delaunay(base[:, :2] - origin)
    except (scipy.spatial.QhullError, ValueError):   # fewer than 3 points, or all on one line
        tin = None
    if tin is not None:
        surface = LinearNDInterpolator(tin, base[:, 2])(xy)
    outside = ~np.isfinite(surface)
    if outside.any():
        _, nearest = scipy.spatial.cKDTree(base[:, :2] - origin).query(xy[outside], workers=-1)
        surface[outside] = base[nearest, 2]
    return xyz[:, 2] - surface
