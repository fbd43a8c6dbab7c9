"""SparseGF's static settings (Qin et al. 2026, Sec. 3.3), in metres."""
from __future__ import annotations

import dataclasses

from gfjax import limits
from gfjax.errors import SettingError
from gfjax.limits import Range
from gfjax.sparsegf.compress import R_IN_M, R_OC_M, R_OO_M
from gfjax.sparsegf.features import FEATURE_SETS
from gfjax.sparsegf.partition import STEP_M

VOXEL_M = 0.5            # voxel edge of the sparse convolutions [m] (Sec. 3.3)
MAX_CONTEXT_POINTS = 10_000

# The valid range of every numeric Config field (`gfjax.limits`).
RANGES: dict[str, Range] = {
    "voxel_m": Range(0, 1e5, low_open=True, high_open=True, unit="m"),
    "step_m": Range(0, 1e5, low_open=True, high_open=True, unit="m"),
    "r_in_m": Range(0, 1e5, low_open=True, high_open=True, unit="m", extra="< r_oc_m"),
    "r_oc_m": Range(0, 1e5, low_open=True, high_open=True, unit="m", extra="<= r_oo_m"),
    "r_oo_m": Range(0, 1e5, low_open=True, high_open=True, unit="m"),
    "max_context_points": Range(1_000, 10_000_000, integer=True),
    "batch_size": Range(1, 64, integer=True),
    "ground_probability": Range(0, 1, low_open=True, high_open=True),
}


@dataclasses.dataclass(frozen=True)
class Config:
    """Static settings of the SparseGF pipeline.

    Attributes:
      voxel_m: voxel edge [m] (0.5; the paper's backbone-only baseline uses 1.0).
      step_m: grid step of the patch centres [m] (50).
      r_in_m, r_oc_m, r_oo_m: inner invariant, outer compressed and outer original radii [m]
        (25 sqrt 2, 44, 150).
      compression: apply the context compression (False: the ablation without it).
      features: the network's per-point inputs: `"xyz"` (the paper's coordinates),
        `"xyz+tophat"` (and the heights over eight opened minimum surfaces) or
        `"xyz+tophat+smrf"` (and the height over SMRF's ground surface and SMRF's margin,
        computed once per cloud; `gfjax.sparsegf.features`, `gfjax.sparsegf.smrf_prior`).
      max_context_points: points per patch at most (all central ones kept; the periphery
        thinned at random with a fixed seed); a CPU budget, not in the paper.
      batch_size: patches per network call at most (they are packed into one sparse tensor).
      ground_probability: a point is ground when its mean vote exceeds this (0.5, Algorithm 1).
    """

    voxel_m: float = VOXEL_M
    step_m: float = STEP_M
    r_in_m: float = R_IN_M
    r_oc_m: float = R_OC_M
    r_oo_m: float = R_OO_M
    compression: bool = True
    features: str = "xyz+tophat+smrf"
    max_context_points: int = MAX_CONTEXT_POINTS
    batch_size: int = 8
    ground_probability: float = 0.5

    def __post_init__(self):
        limits.check_fields(self, RANGES)
        if self.features not in FEATURE_SETS:
            raise SettingError(f"features must be one of {FEATURE_SETS}, got {self.features!r}", "features")
        if not self.r_in_m < self.r_oc_m <= self.r_oo_m:
            raise SettingError(f"r_in_m < r_oc_m <= r_oo_m needed, got {self.r_in_m}, {self.r_oc_m}, {self.r_oo_m}",
                               "r_in_m", "r_oc_m", "r_oo_m")


PRESETS: dict[str, dict] = {
    "no-compression": {"compression": False, "voxel_m": 1.0},
}
