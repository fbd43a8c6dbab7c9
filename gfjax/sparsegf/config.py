"""SparseGF's static settings (Qin et al. 2026, Sec. 3.3), in metres."""
from __future__ import annotations

import dataclasses

from gfjax.sparsegf.compress import R_IN_M, R_OC_M, R_OO_M
from gfjax.sparsegf.partition import STEP_M

VOXEL_M = 0.5            # voxel edge of the sparse convolutions [m] (Sec. 3.3)
MAX_CONTEXT_POINTS = 60_000


@dataclasses.dataclass(frozen=True)
class Config:
    """Static settings of the SparseGF pipeline.

    Attributes:
      voxel_m: voxel edge [m] (0.5; the paper's backbone-only baseline uses 1.0).
      step_m: grid step of the patch centres [m] (50).
      r_in_m, r_oc_m, r_oo_m: inner invariant, outer compressed and outer original radii [m]
        (25 sqrt 2, 44, 150).
      compression: apply the context compression (False: the ablation without it).
      max_context_points: points per patch at most (all central ones kept; the periphery
        thinned at random with a fixed seed); a CPU budget, not in the paper.
      batch_size: patches per network call.
      ground_probability: a point is ground when its mean vote exceeds this (0.5, Algorithm 1).
    """

    voxel_m: float = VOXEL_M
    step_m: float = STEP_M
    r_in_m: float = R_IN_M
    r_oc_m: float = R_OC_M
    r_oo_m: float = R_OO_M
    compression: bool = True
    max_context_points: int = MAX_CONTEXT_POINTS
    batch_size: int = 1
    ground_probability: float = 0.5

    def __post_init__(self):
        for name in ("voxel_m", "step_m", "r_in_m", "r_oc_m", "r_oo_m"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0 and value < 1e5):
                raise ValueError(f"{name} must be in (0, 1e5) m, got {value}")
        if not self.r_in_m < self.r_oc_m <= self.r_oo_m:
            raise ValueError(f"r_in_m < r_oc_m <= r_oo_m needed, got {self.r_in_m}, {self.r_oc_m}, {self.r_oo_m}")
        if not 1_000 <= self.max_context_points <= 10_000_000:
            raise ValueError(f"max_context_points must be in [1000, 1e7], got {self.max_context_points}")
        if not 1 <= self.batch_size <= 64:
            raise ValueError(f"batch_size must be in [1, 64], got {self.batch_size}")
        if not 0.0 < self.ground_probability < 1.0:
            raise ValueError(f"ground_probability must be in (0, 1), got {self.ground_probability}")


PRESETS: dict[str, dict] = {
    "no-compression": {"compression": False, "voxel_m": 1.0},
}
