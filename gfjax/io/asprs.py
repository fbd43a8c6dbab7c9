"""ASPRS LAS class codes, and what a filter does with each (`ClassRules`)."""
from __future__ import annotations

import dataclasses
from collections.abc import Set as AbstractSet

import laspy
import numpy as np

from gfjax.errors import SettingError

NEVER_CLASSIFIED = 0
UNCLASSIFIED = 1
GROUND = 2
LOW_NOISE = 7
WATER = 9
HIGH_NOISE = 18
NOISE_CLASSES = (LOW_NOISE, HIGH_NOISE)


@dataclasses.dataclass(frozen=True)
class ClassRules:
    """What a filter does with the points of each class code (0-255).

    Every point is one of three kinds:
    - ignored: its class is in `ignore`, or it is withheld. No filter uses it and its class never
      changes. Noise (7, 18) is always ignored: a low return under the terrain would pull a
      ground surface down.
    - kept: its class is in `keep`. Filters use it (a building or water point is context for the
      ground beside it) but its class never changes: classes a user already has survive.
    - the rest: used, and labelled ground (2) or not (former ground becomes 1).

    Attributes:
      ignore: the ignored codes (any iterable of ints; noise 7 and 18 are added).
      keep: the kept codes.
    """

    ignore: AbstractSet[int] = frozenset(NOISE_CLASSES)
    keep: AbstractSet[int] = frozenset()

    def __post_init__(self):
        for name in ("ignore", "keep"):
            codes = frozenset(int(c) for c in getattr(self, name))
            bad = sorted(c for c in codes if not 0 <= c <= 255)
            if bad:
                raise SettingError(f"{name} classes must be ASPRS codes 0-255, got {bad[0]}", name)
            object.__setattr__(self, name, codes)
        object.__setattr__(self, "ignore", self.ignore | frozenset(NOISE_CLASSES))

    def ignored(self, las: laspy.LasData | laspy.PackedPointRecord) -> np.ndarray:
        """Points (of a file, or of a chunk of its points) that no filter uses and whose class
        never changes: a class in `ignore`, or withheld. bool `(n,)`."""
        ignored = np.isin(np.asarray(las.classification), sorted(self.ignore))
        if "withheld" in set(las.point_format.dimension_names):
            ignored |= np.asarray(las.withheld, dtype=bool)
        return ignored

    def kept(self, classification: np.ndarray) -> np.ndarray:
        """Points whose class is in `keep`, bool `(n,)`: used, never relabelled."""
        return np.isin(np.asarray(classification), sorted(self.keep))

    def describe(self) -> str:
        """`ignored 7, 9, 18; kept 6` for messages."""
        keep = f"; kept {', '.join(map(str, sorted(self.keep)))}" if self.keep else ""
        return f"ignored {', '.join(map(str, sorted(self.ignore)))}{keep}"


DEFAULT_RULES = ClassRules()


def ignored_mask(las: laspy.LasData | laspy.PackedPointRecord, rules: ClassRules = DEFAULT_RULES) -> np.ndarray:
    """Points (of a file, or of a chunk of its points) that no filter uses and whose class never
    changes (`ClassRules.ignored`; by default noise 7, 18 and withheld points). bool `(n,)`."""
    return rules.ignored(las)


def relabel(classification: np.ndarray, ground: np.ndarray, used: np.ndarray, *,
            reset_nonground: bool = False, rules: ClassRules = DEFAULT_RULES) -> np.ndarray:
    """New classes uint8 `(n,)` for a filter's labels (SPEC section 1): used ground points get
    class 2; used non-ground points that were 2 become 1, and the other used non-ground points
    keep their class unless `reset_nonground` (then all become 1); points not `used` and points
    of the classes `rules` keeps keep their class whatever `ground` says."""
    cls = np.asarray(classification, np.uint8)
    ground = np.asarray(ground, bool)
    used = np.asarray(used, bool) & ~rules.kept(cls)
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
