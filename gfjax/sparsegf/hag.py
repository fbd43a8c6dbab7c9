"""Height-above-ground (HAG) training targets for SparseGF's height-aware loss (Sec. 2.2.2, 3.3).

HAG = z - DTM_ref(x, y), where DTM_ref is the TIN (linear interpolation on a Delaunay
triangulation) of the labelled ground points (ASPRS class 2); outside the ground points'
convex hull the surface takes the height of the nearest ground point. The continuous HAG is
quantised into the paper's six bins (Sec. 3.3):

    bin 0  ground                        (labelled ground, whatever its HAG)
    bin 1  (0, 0.2] m   low grass        (+ non-ground at or below the surface, HAG <= 0)
    bin 2  (0.2, 0.5] m low shrubs
    bin 3  (0.5, 1] m   medium shrubs
    bin 4  (1, 3] m     low structures or small trees
    bin 5  (3, inf) m   tall structures or large trees

Every class other than 2 is non-ground: ISPRS "object" (0), unclassified (1), water (9) and
noise (7, 18; the paper relabels outliers as non-ground for training, Sec. 3.3).

Host code (numpy + scipy Delaunay / cKDTree), run once per training cloud outside jit.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gfjax.errors import InputError

GROUND_CLASS = 2
HAG_BIN_EDGES_M = (0.2, 0.5, 1.0, 3.0)   # upper bounds of bins 1..4 [m]; bin 5 is (3, inf)
N_HAG_BINS = 6


class HagTargets(NamedTuple):
    """Attributes:
      hag_m: `(n,)` float64, z minus the reference ground surface at (x, y) [m]
        (about 0 on ground points; negative below the surface).
      bins: `(n,)` int32 in `0..5`, the HAG bin (0 exactly for ground points).
      ground: `(n,)` bool, `classification == 2`, the ground/non-ground label.
    """

    hag_m: np.ndarray
    bins: np.ndarray
    ground: np.ndarray


def hag_bins(hag_m: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """Bin index `(n,)` int32: 0 for ground; for non-ground `1 + #{edges < hag}` (Sec. 3.3).

    Non-ground points at or below the surface (`hag_m <= 0`) fall in bin 1, the lowest
    non-zero bin; bin upper bounds are inclusive (`(0.2, 0.5]`).
    """
    above = np.searchsorted(np.asarray(HAG_BIN_EDGES_M), np.asarray(hag_m), side="left")
    return np.where(np.asarray(ground, dtype=bool), 0, 1 + above).astype(np.int32)


def ground_surface(ground_xyz_m: np.ndarray, xy_m: np.ndarray) -> np.ndarray:
    """Height `(m,)` of the TIN of `ground_xyz_m` `(g, 3)` at `xy_m` `(m, 2)` [m].

    Linear interpolation on the Delaunay triangulation of the ground points (float64,
    relative to their minimum corner); the nearest ground point's z outside the convex hull,
    and everywhere when the ground points span no triangle (fewer than 3, or collinear).
    """
    # training only: filtering imports this module for its bin count and never pays for scipy
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import Delaunay, QhullError, cKDTree

    g_xy = ground_xyz_m[:, :2] - ground_xyz_m[:, :2].min(axis=0)
    xy = xy_m - ground_xyz_m[:, :2].min(axis=0)
    z = ground_xyz_m[:, 2]
    surface = np.full(len(xy), np.nan)
    if len(g_xy) >= 3:
        try:
            surface = LinearNDInterpolator(Delaunay(g_xy), z)(xy)
        except QhullError:
            pass                                   # degenerate (collinear) ground: nearest only
    outside = np.isnan(surface)
    if np.any(outside):
        _, nearest = cKDTree(g_xy).query(xy[outside])
        surface[outside] = z[nearest]
    return surface


def hag_targets(xyz_m: np.ndarray, classification: np.ndarray) -> HagTargets:
    """HAG and its bin for every point of a labelled cloud (SPEC section 5, paper Sec. 3.3).

    Args:
      xyz_m: points `(n, 3)`, metres (use `Cloud.xyz_m`: feet data must be converted).
      classification: ASPRS classes `(n,)`; class 2 is ground, all others non-ground.

    Returns:
      `HagTargets(hag_m, bins, ground)`.

    Raises:
      InputError: bad shapes, non-finite coordinates, or no ground point to build a TIN.
    """
    xyz_m = np.asarray(xyz_m, dtype=np.float64)
    cls = np.asarray(classification)
    if xyz_m.ndim != 2 or xyz_m.shape[1] != 3:
        raise InputError(f"hag_targets: xyz_m must have shape (n, 3), got {xyz_m.shape}")
    if cls.shape != xyz_m.shape[:1]:
        raise InputError(f"hag_targets: classification must have shape {xyz_m.shape[:1]}, got {cls.shape}")
    if not np.all(np.isfinite(xyz_m)):
        raise InputError("hag_targets: xyz_m has non-finite coordinates")
    ground = cls == GROUND_CLASS
    if not np.any(ground):
        raise InputError("hag_targets: no ground points (class 2); HAG targets need labelled ground")
    hag_m = xyz_m[:, 2] - ground_surface(xyz_m[ground], xyz_m[:, :2])
    return HagTargets(hag_m=hag_m, bins=hag_bins(hag_m, ground), ground=ground)
