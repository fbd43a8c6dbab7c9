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


def ignored_mask(las: laspy.LasData | laspy.PackedPointRecord) -> np.ndarray:
    """Points (of a file, or of a chunk of its points) that no filter uses and whose class never
    changes: noise (7, 18) or withheld.

    Returns a bool array `(n,)`.
    """
    cls = np.asarray(las.classification)
    ignored = np.isin(cls, NOISE_CLASSES)
    names = set(las.point_format.dimension_names)
    if "withheld" in names:
        ignored |= np.asarray(las.withheld, dtype=bool)
    return ignored


def relabel(classification: np.ndarray, ground: np.ndarray, used: np.ndarray, *,
            reset_nonground: bool = False) -> np.ndarray:
    """New classes uint8 `(n,)` for a filter's labels (SPEC section 1): used ground points get
    class 2; used non-ground points that were 2 become 1, and the other used non-ground points
    keep their class unless `reset_nonground` (then all become 1); points not `used` keep
    their class whatever `ground` says."""
    cls = np.asarray(classification, np.uint8)
    ground, used = np.asarray(ground, bool), np.asarray(used, bool)
    new = cls.copy()
    new[ground & used] = GROUND
    nonground = ~ground & used
    if reset_nonground:
        new[nonground] = UNCLASSIFIED
    else:
        new[nonground & (cls == GROUND)] = UNCLASSIFIED
    return new


# ASPRS LAS 1.4 R15, table 17 (point formats 6-10); codes 0-12 as in LAS 1.2 table 5 except
# where noted. Codes 23-63 are reserved and 64-255 user definable.
CLASS_NAMES: dict[int, str] = {
    0: "created, never classified",
    1: "unclassified",
    2: "ground",
    3: "low vegetation",
    4: "medium vegetation",
    5: "high vegetation",
    6: "building",
    7: "low point (noise)",
    8: "model key-point (LAS 1.2) / reserved",
    9: "water",
    10: "rail",
    11: "road surface",
    12: "overlap (LAS 1.2) / reserved",
    13: "wire - guard (shield)",
    14: "wire - conductor (phase)",
    15: "transmission tower",
    16: "wire-structure connector",
    17: "bridge deck",
    18: "high noise",
    19: "overhead structure",
    20: "ignored ground",
    21: "snow",
    22: "temporal exclusion",
}


def class_name(code: int) -> str:
    """The ASPRS name of class `code` ("reserved" 23-63, "user defined" 64-255)."""
    code = int(code)
    if code in CLASS_NAMES:
        return CLASS_NAMES[code]
    if 23 <= code <= 63:
        return "reserved"
    if 64 <= code <= 255:
        return "user defined"
    raise ValueError(f"ASPRS class codes are 0-255, got {code}")


def class_counts(las: laspy.LasData) -> dict[int, int]:
    """Number of points per class code present in `las`, ascending by code."""
    codes, counts = np.unique(np.asarray(las.classification, dtype=np.uint8), return_counts=True)
    return {int(c): int(k) for c, k in zip(codes, counts)}
