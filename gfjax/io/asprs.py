"""ASPRS LAS class codes and the points filters ignore."""
from __future__ import annotations

import laspy
import numpy as np

NEVER_CLASSIFIED = 0
UNCLASSIFIED = 1
GROUND = 2
LOW_NOISE = 7
WATER = 9
HIGH_NOISE = 18
NOISE_CLASSES = (LOW_NOISE, HIGH_NOISE)


def ignored_mask(las: laspy.LasData) -> np.ndarray:
    """Points that no filter uses and whose class never changes: noise (7, 18) or withheld.

    Returns a bool array `(n,)`.
    """
    cls = np.asarray(las.classification)
    ignored = np.isin(cls, NOISE_CLASSES)
    names = set(las.point_format.dimension_names)
    if "withheld" in names:
        ignored |= np.asarray(las.withheld, dtype=bool)
    return ignored
