"""SMRF static configuration and traced parameters (Pingel, Clarke & McBride 2013).

`Config` holds what changes shapes or loop counts (cell size, window, tiling) and is a
hashable static argument of the jitted stages; `Params` holds the thresholds optax may tune
(traced, so tuning never recompiles). Defaults are PDAL's documented `filters.smrf` values
(SPEC section 6): cell 1 m, window 18 m, slope 0.15, threshold 0.5 m, scalar 1.25.
"""
from __future__ import annotations

import dataclasses
import math

from jaxtyping import Array, Float

from gfjax import adaptive, limits, params
from gfjax.errors import SettingError
from gfjax.limits import Range
from gfjax.params import param
from gfjax.tiling import tiles

__all__ = ["Config", "Params", "PRESETS", "INPAINT_METHODS", "RANGES", "adapt"]

INPAINT_METHODS = ("harmonic", "nearest")

# The valid range of every numeric Config / Params field (`gfjax.limits`; the table of `docs/cli.md`
# of checked ranges is generated from these tables).
RANGES: dict[str, Range] = {
    "cell_m": Range(0, 100, low_open=True, unit="m"),
    "window_m": Range(0, 10_000, low_open=True, unit="m", extra=">= cell_m, <= 1000 cell_m"),
    "low_outlier_slope": Range(0, 1000, low_open=True),
    "low_outlier_radius_px": Range(1, 100, integer=True, unit="cells"),
    "inpaint_max_iter": Range(1, 1_000_000, integer=True),
    "inpaint_tol_m": Range(0, 100, low_open=True, unit="m"),
    "slope": Range(0, 100),
    "threshold_m": Range(0, 1000, unit="m"),
    "scalar": Range(0, 1000),
}
MAX_WINDOW_PX = 1000          # window_m / cell_m: the largest opening radius, in cells
MAX_BATCH = 8                 # tiles per vmap call of `gfjax.smrf.filter`


@dataclasses.dataclass(frozen=True)
class Config:
    """Static SMRF settings (hashable: a `static_argnames` value).

    Attributes:
      cell_m: raster cell side [m] (Pingel et al. 2013, Sec. 2.1, "c").
      window_m: largest structuring-element radius [m]; radii run 1..`max_radius_px` cells
        (Sec. 2.2, "omega").
      low_outlier_slope: slope of the one-cell progressive filter applied to -ZImin that
        marks low-outlier cells (Sec. 2.1; PDAL uses 5.0) [-].
      low_outlier_radius_px: window of that filter [cells] (1 in the paper).
      inpaint: how empty and removed cells are filled, "harmonic" (Laplace) or "nearest".
      inpaint_max_iter: iteration cap of the harmonic fill.
      inpaint_tol_m: stopping tolerance of the harmonic fill (max update) [m].
    """

    cell_m: float = 1.0
    window_m: float = 18.0
    low_outlier_slope: float = 5.0
    low_outlier_radius_px: int = 1
    inpaint: str = "harmonic"
    inpaint_max_iter: int = 2000
    inpaint_tol_m: float = 1e-3

    def __post_init__(self) -> None:
        limits.check_fields(self, RANGES)
        checks = [
            (self.window_m >= self.cell_m, "window_m must be >= cell_m", ("window_m", "cell_m")),
            (self.window_m <= MAX_WINDOW_PX * self.cell_m,
             f"window_m must be <= {MAX_WINDOW_PX} cell_m (window_m / cell_m sets the opening loop)",
             ("window_m", "cell_m")),
            (self.inpaint in INPAINT_METHODS, f"inpaint must be one of {INPAINT_METHODS}", ("inpaint",)),
        ]
        for ok, message, keys in checks:
            if not ok:
                raise SettingError(f"{message}, got {getattr(self, keys[0])!r}", *keys)

    # The largest allocations these settings imply with a tiling (`gfjax.tiling.tiles.Tiling`),
    # checked against the memory budget where a job starts: per tile cell about 32 float32 or
    # int32 rasters (stage inputs, work arrays, diagnostics: an estimate, not a measurement),
    # per cloud cell six float64 diagnostics rasters.
    memory_estimates = tiles.tiled_estimator(max_batch=MAX_BATCH, tile_bytes_per_cell=32 * 4,
                                              mosaic_bytes_per_cell=6 * 8)

    @property
    def max_radius_px(self) -> int:
        """Largest opening radius in cells: `ceil(window_m / cell_m)` (metres -> pixels, once)."""
        return max(1, math.ceil(self.window_m / self.cell_m - 1e-9))


class Params(params.Params):
    """Traced SMRF thresholds (float32 scalars; optax may tune them).

    Attributes:
      slope: terrain slope tolerated by the progressive filter, rise over run [-] ("s").
      threshold_m: elevation threshold of the final point test [m] ("elevation threshold").
      scalar: weight of the local ZIpro slope in the final test [m per unit slope]
        ("elevation scalar"): ground iff `|z - ZIpro| <= threshold_m + scalar * slope_local`.
    """

    ranges = RANGES

    slope: Float[Array, ""] = param(0.15)
    threshold_m: Float[Array, ""] = param(0.5)
    scalar: Float[Array, ""] = param(1.25)



# Named overrides for `--preset` (`gfjax filter --method smrf --preset NAME`). "nearest-fill"
# inpaints empty and removed cells from the nearest filled cell instead of the harmonic fill
# (SPEC section 6: a numpy prototype measured 4.0 % vs 3.3 % mean total error on the 11 ISPRS
# samples; closer to PDAL, whose filters.smrf fills by nearest neighbours).
PRESETS: dict[str, dict[str, object]] = {
    "nearest-fill": {"inpaint": "nearest"},
    adaptive.FIXED_PRESET: {"cell_m": 1.0},
}

# Low outliers hidden from SMRF too (`gfjax.low_outliers`), although its own stage (Pingel et al. 2013,
# Sec. 2.1: `stages.low_outliers`) removes single cells of them: a cluster over several cells stays in
# its minimum surface. On the training files (`experiments/results/low_outliers_methods.md`) all 21
# pass either way, mean total error 11.29 -> 11.25 %, ISPRS 3.40 -> 3.29 % (samp41 6.32 -> 5.57 %).
HIDES_LOW_OUTLIERS = True


def adapt(terrain: adaptive.Terrain) -> dict[str, float]:
    """SMRF's values that follow the cloud (`gfjax.adaptive`): the cell, coarser for sparse
    last returns (`adaptive.raster_cell_m`); a cell coarser than a third of the window (a
    cloud spread thinner than `adaptive.cost_cell_m` allows) widens the window to three
    cells, so the opening still grows over three radii."""
    cell = adaptive.raster_cell_m(terrain)
    window = Config().window_m
    return {"cell_m": cell} if 3 * cell <= window else {"cell_m": cell, "window_m": 3 * cell}
