"""PMF static configuration and traced parameters (Zhang et al. 2003).

Defaults (SPEC section 6; PDAL `filters.pmf`): cell 1 m, max window 33 m, slope 1, initial
distance 0.15 m, max distance 2.5 m, exponential window growth `w_k = 2 b^k + 1` cells, b = 2.
"""
from __future__ import annotations

import dataclasses

from jaxtyping import Array, Float

from gfjax import adaptive, limits, params
from gfjax.errors import SettingError
from gfjax.limits import Range
from gfjax.params import param
from gfjax.tiling import tiles

__all__ = ["Config", "Params", "PRESETS", "RANGES", "adapt"]

# The valid range of every numeric Config / Params field (`gfjax.limits`).
RANGES: dict[str, Range] = {
    "cell_m": Range(0, 100, low_open=True, unit="m"),
    "max_window_m": Range(0, 10_000, low_open=True, unit="m", extra="<= 1000 cell_m"),
    "base": Range(2, 16, integer=True),
    "slope": Range(0, 100),
    "initial_distance_m": Range(0, 1000, unit="m"),
    "max_distance_m": Range(0, 1000, unit="m"),
}
MAX_WINDOW_PX = 1000          # max_window_m / cell_m: the largest window, in cells
MAX_BATCH = 8                 # tiles per vmap call of `gfjax.pmf.filter`


@dataclasses.dataclass(frozen=True)
class Config:
    """Static PMF settings (hashable: a `static_argnames` value).

    Attributes:
      cell_m: raster cell side [m] ("c" in Zhang et al. 2003, Eq. 4).
      max_window_m: the windows grow until one reaches this size [m] (PDAL `max_window_size`).
      exponential: window sizes `2 b^k + 1` cells (Zhang et al. 2003, Eq. 5) if True, else
        linear `2 k b + 1` cells (Eq. 4).
      base: b of the window series [-].
    """

    cell_m: float = 1.0
    max_window_m: float = 33.0
    exponential: bool = True
    base: int = 2

    def __post_init__(self) -> None:
        limits.check_fields(self, RANGES)
        if not isinstance(self.exponential, bool):
            raise SettingError(f"exponential must be a bool, got {self.exponential!r}", "exponential")
        if self.max_window_m > MAX_WINDOW_PX * self.cell_m:
            raise SettingError(f"max_window_m must be <= {MAX_WINDOW_PX} cell_m (max_window_m / cell_m sets the "
                               f"largest window), got {self.max_window_m!r}", "max_window_m", "cell_m")

    # The largest allocations these settings imply with a tiling (`gfjax.tiling.tiles.Tiling`),
    # checked against the memory budget where a job starts: per tile cell about 16 float32 or
    # int32 rasters (stage inputs, work arrays, diagnostics: an estimate, not a measurement),
    # per cloud cell three float64 diagnostics rasters.
    memory_estimates = tiles.tiled_estimator(max_batch=MAX_BATCH, tile_bytes_per_cell=16 * 4,
                                              mosaic_bytes_per_cell=3 * 8)

    @property
    def windows_px(self) -> tuple[int, ...]:
        """Window sizes in cells, `w_k = 2 b^k + 1` (or `2 k b + 1`), k = 0, 1, ...: the series
        stops after the first window of at least `max_window_m` (PDAL's `while (ws < max)` loop:
        3, 5, 9, 17, 33 cells for the defaults)."""
        sizes: list[int] = []
        k = 0
        while not sizes or sizes[-1] * self.cell_m < self.max_window_m - 1e-9:
            sizes.append(2 * self.base ** k + 1 if self.exponential else 2 * (k + 1) * self.base + 1)
            k += 1
        return tuple(sizes)


class Params(params.Params):
    """Traced PMF thresholds (float32; optax may tune them).

    Attributes:
      slope: terrain slope, rise over run [-] ("s", Eq. 7).
      initial_distance_m: elevation threshold of the first window [m] ("dh0").
      max_distance_m: cap on the elevation threshold [m] ("dh_max").
    """

    ranges = RANGES

    slope: Float[Array, ""] = param(1.0)
    initial_distance_m: Float[Array, ""] = param(0.15)
    max_distance_m: Float[Array, ""] = param(2.5)



# Coarse scene types (not per-sample values).
PRESETS: dict[str, dict[str, float]] = {
    "urban": {"max_window_m": 33.0, "slope": 1.0, "initial_distance_m": 0.15, "max_distance_m": 2.5},
    "steep": {"max_window_m": 17.0, "slope": 1.5, "initial_distance_m": 0.3, "max_distance_m": 3.0},
    "flat": {"max_window_m": 65.0, "slope": 0.5, "initial_distance_m": 0.15, "max_distance_m": 2.0},
}
PRESETS[adaptive.FIXED_PRESET] = {"cell_m": 1.0, "initial_distance_m": 0.15, "max_distance_m": 2.5}

# What follows the cloud, chosen among candidates on the training files of
# `experiments.common.LABELLED` by leave-one-survey-out (`experiments/results/adaptive_rules_pmf.md`:
# 18 of 21 files pass, 12 with the fixed values): the cell of SMRF's rule; a first threshold
# of 0.5 m (0.15 m takes rough or noisy ground for objects: half the ground of a flat forest);
# a threshold cap that lets the largest window follow the steep slopes (PDAL's 2.5 m cuts off
# mountain ground once the window spans more than 2.5 m of rise).
INITIAL_DISTANCE_M = 0.5


# Low outliers hidden before the openings (`gfjax.low_outliers`): an opening spreads a return far below
# the terrain over its window. On the training files (`experiments/results/low_outliers_methods.md`) samp41's
# DTM RMSE falls from 1.56 to 0.39 m, samp31's type I from 3.6 % to 0.2 %; no file fails that passed.
HIDES_LOW_OUTLIERS = True


def adapt(terrain: adaptive.Terrain) -> dict[str, float]:
    """PMF's values that follow the cloud (`gfjax.adaptive`): `cell_m` (`adaptive.raster_cell_m`),
    `initial_distance_m` = 0.5 m, and `max_distance_m` = the rise of the 90th-percentile slope over
    half the largest window, at least 2.5 m."""
    half_window_m = Config().max_window_m / 2
    return {"cell_m": adaptive.raster_cell_m(terrain), "initial_distance_m": INITIAL_DISTANCE_M,
            "max_distance_m": max(2.5, round(terrain.slope_p90 * half_window_m, 2))}
