"""MASF static configuration, traced parameters and presets (Cao et al. 2024; SPEC section 4).

`Config` holds what changes shapes or loop counts (grid, the alpha pyramid, outlier rules);
`Params` holds the two thresholds that enter the TIN-densification distance test,
`DT_k = st * alpha_k + ft_m` (Eq. 2) and the final `ft_m`. The densification runs on the host
(scipy triangulations), so gradients through `Params` are zero there: tune them on a grid.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from jaxtyping import Array, Float

from gfjax import adaptive, limits, params
from gfjax.errors import SettingError
from gfjax.limits import Range
from gfjax.params import param

__all__ = ["Config", "Params", "PRESETS", "adapt", "PAPER_TABLE3", "DISTANCES", "RANGES"]

DISTANCES = ("under", "nearest_facet")
BUFFER_HEIGHTS = ("top", "nearest", "extrapolated")     # `gfjax.masf.densify.buffer_z`

# The valid range of every numeric Config / Params field (`gfjax.limits`).
RANGES: dict[str, Range] = {
    "grid_m": Range(0, 100, low_open=True, unit="m"),
    "alpha_max_m": Range(0, 10_000, low_open=True, unit="m", extra=">= alpha_min"),
    "alpha_step_m": Range(0, 10_000, low_open=True, unit="m", extra="at most 1000 layers"),
    "alpha_min_m": Range(0, 10_000, low_open=True, unit="m", none_ok=True),
    "alpha_top_m": Range(0, 100_000, low_open=True, unit="m", none_ok=True, extra="> alpha_max_m"),
    "outlier_gap_m": Range(0, 1000, low_open=True, unit="m"),
    "neighbour_drop_m": Range(0, 1000, low_open=True, unit="m"),
    "low_cluster_max_m2": Range(0, 1_000_000, unit="m^2"),
    "pit_slope": Range(0, 100, none_ok=True),
    "pit_cap_m": Range(0, 10_000, unit="m"),
    "layer_passes": Range(1, 100, integer=True),
    "empty_tol_m": Range(0, 10, unit="m"),
    "mirror_max_m": Range(0, 1000, low_open=True, unit="m", none_ok=True),
    "st": Range(0, 100),
    "ft_m": Range(0, 1000, unit="m"),
}
MAX_LAYERS = 1000             # (alpha_max_m - alpha_min) / alpha_step_m + 1: the layer loop
_GRID_BYTES_PER_CELL = 8 * 8  # the preprocessing grid: a few float64 / int64 arrays per cell



@dataclasses.dataclass(frozen=True)
class Config:
    """Static MASF settings (hashable).

    Attributes:
      grid_m: preprocessing grid cell [m] (Sec. 2.1; 1 m "in most cases").
      alpha_max_m: alpha of the first layer of the linear pyramid, Eq. 1 [m]. 25 m, the largest
        of the paper's Table 3 (half the largest object: buildings up to 50 m wide), with the
        buffer heights and the mirror test below, won over 20 and 30 m on the training files,
        held out survey by survey too (`experiments/results/adaptive_rules_masf.md`).
      alpha_step_m: decrement between layers, Eq. 1 [m].
      alpha_min_m: smallest alpha; None means `2 * grid_m` (Sec. 2.3) [m].
      alpha_top_m: optional alpha of an extra top layer above `alpha_max_m` (the paper's samp42
        uses 90 m, then 20 m downward in 9 m steps) [m]; None = no extra layer.
      outlier_gap_m: extended local minimum: walking up a cell's points sorted by z, a gap to
        the next point larger than this marks the lower point an outlier (our choice) [m].
      neighbour_drop_m: a potential ground point more than this below the lowest potential
        ground point of its occupied neighbour cells (3x3, else 5x5) is a low outlier (R) [m].
      neighbour_test: run the neighbourhood test of `neighbour_drop_m` and `low_cluster_max_m2`
        (SPEC 4.1). `adapt` leaves it out: a run whose values follow the cloud hides its low
        outliers first (`gfjax.low_outliers`, which asks for company around and terrain far
        above), and in a sparse forest this test takes ground seen through the canopy, below
        the canopy returns of every cell around it, for a low outlier (R).
      low_cluster_max_m2: the neighbourhood test applies to connected clusters of potential
        ground cells (linked within 5x5 when their z differ by at most `neighbour_drop_m`) up to
        this area: a cluster every link out of which goes up is a low outlier patch (R) [m^2].
      pit_slope: top-layer seeds joined by a TIN edge are linked when their z differ by at most
        `neighbour_drop_m + pit_slope * min(edge length, pit_cap_m)`; a linked group of seeds
        (fewer than half of them) all of whose other edges climb is a pit of low outliers and
        leaves the seeds (R, see `densify.low_seed_pits`) [-]; None switches the test off.
      pit_cap_m: edge length beyond which the allowed step stops growing [m].
      distance: point-to-TIN distance of the densification: "under" (SPEC 4.4: perpendicular
        to the plane of the facet under the point) or "nearest_facet" (the paper's Fig. 7a
        wording: 3D distance to the nearest facet, searched among the facet under the point
        and its edge neighbours).
      layer_passes: most passes of the densification test per layer (1: one pass; more: the
        layer's remaining points are retested against the TIN holding the points just
        accepted, until a pass adds none) (R; the paper calls its densification
        "noniterative", "ground points are only identified once in each layer": a point is
        still accepted at most once, but a rejected one is tested again). 3 won leave-one-out
        against 1 on the 11 ISPRS samples with both the default set and the paper's values
        (`experiments/results/masf_isprs.md`); the TIN grows by batch insertion, so the extra
        passes cost little.
      retest_earlier: at each layer, points of earlier layers not yet ground are tested again
        against the current TIN with the DT of the first layer that held them (R).
      retriangulate: the reference path of the densification: triangulate the TIN again with
        Qhull after every pass instead of inserting the accepted points (slow; the same labels
        in general position, `experiments/masf_isprs.py` counts the differences on ties).
      empty_tol_m: tolerance of the empty-sphere test along the dual Voronoi edge [m].
      buffer_heights: heights of the simulated ground points around the grid (Sec. 2.4):
        "top" (the paper: z of the nearest top-layer point), "nearest" or "extrapolated" (R:
        taken again before each lower layer from the nearest ground point of the TIN, plus
        its slope times the offset for "extrapolated"; `densify.buffer_z`), so the TIN can
        climb a slope that rises to the edge of the cloud.
      mirror_max_m: a point of a layer closer than this to the TIN also joins it when its
        mirror image through the nearest ground corner of the facet under it is within DT_k
        (Axelsson's mirror points, R: ground on ridges and terrace edges, which only the
        small balls of the last layers reach, stands above the TIN of the coarser layers by
        more than their DT) [m]; None: no mirror test (the paper). The centre is a point that
        joined by its own distance: with any ground vertex as centre, a roof whose edge got in
        was followed point by point (a survey's window of the synthetic town took 99 roof
        points the whole cloud does not). 1.5 m: all 21 training files pass, and 14 of the 15
        surveys held out pick it (`experiments/results/adaptive_rules_masf.md`).
    """

    grid_m: float = 1.0
    alpha_max_m: float = 25.0
    alpha_step_m: float = 2.0
    alpha_min_m: float | None = None
    alpha_top_m: float | None = None
    outlier_gap_m: float = 1.0
    neighbour_drop_m: float = 1.0
    neighbour_test: bool = True
    low_cluster_max_m2: float = 1.0
    pit_slope: float | None = 1.0
    pit_cap_m: float = 4.0
    distance: str = "under"
    layer_passes: int = 3
    retest_earlier: bool = False
    retriangulate: bool = False
    empty_tol_m: float = 1e-3
    buffer_heights: str = "extrapolated"
    mirror_max_m: float | None = 1.5

    def __post_init__(self) -> None:
        limits.check_fields(self, RANGES)
        if self.distance not in DISTANCES:
            raise SettingError(f"distance must be one of {DISTANCES}, got {self.distance!r}", "distance")
        if self.buffer_heights not in BUFFER_HEIGHTS:
            raise SettingError(f"buffer_heights must be one of {BUFFER_HEIGHTS}, got {self.buffer_heights!r}",
                               "buffer_heights")
        if self.alpha_max_m < self.min_alpha_m:
            raise SettingError(f"alpha_max_m must be >= alpha_min_m ({self.min_alpha_m}), got {self.alpha_max_m!r}",
                               "alpha_max_m")
        if self.alpha_top_m is not None and not (math.isfinite(self.alpha_top_m) and self.alpha_top_m > self.alpha_max_m):
            raise SettingError(f"alpha_top_m must be finite and > alpha_max_m ({self.alpha_max_m}), "
                               f"got {self.alpha_top_m!r}", "alpha_top_m", "alpha_max_m")
        layers = (self.alpha_max_m - self.min_alpha_m) / self.alpha_step_m + 1
        if layers > MAX_LAYERS:
            raise SettingError(f"alpha_step_m must give at most {MAX_LAYERS} layers ((alpha_max_m - alpha_min) / "
                               f"alpha_step_m + 1 = {layers:,.0f}), got {self.alpha_step_m!r}",
                               "alpha_step_m", "alpha_max_m")

    def memory_estimates(self, extent_m: tuple[float, float] | None = None) -> list[limits.Estimate]:
        """The largest allocation these settings imply, checked by `gfjax.limits.check_memory` where a
        job starts (`gfjax.methods.make_config_and_params`, `gfjax.tiling.checks.checked_options`): with
        `extent_m` (the cloud's x, y extent [m]), the preprocessing grid over the whole cloud."""
        if extent_m is None:
            return []
        w, h = (limits.raster_side(e, self.grid_m) for e in extent_m)
        return [limits.Estimate(f"a grid of {h:,} x {w:,} cells (extent / grid_m)",
                                float(h) * float(w) * _GRID_BYTES_PER_CELL, ("grid_m",))]

    @property
    def min_alpha_m(self) -> float:
        """alpha_min: `alpha_min_m`, or twice the grid cell (Sec. 2.3) [m]."""
        return 2.0 * self.grid_m if self.alpha_min_m is None else float(self.alpha_min_m)

    @property
    def reach_m(self) -> float:
        """How far apart two points can sit and still meet in one triangle of the pyramid: the
        largest alpha circle's diameter, `2 max(alpha_max, alpha_top)` [m]. Groups of points
        farther apart never interact (what `gfjax.tiling.groups` may move)."""
        return 2.0 * max(self.alpha_max_m, self.alpha_top_m or 0.0)

    @property
    def low_cluster_max_cells(self) -> int:
        """`low_cluster_max_m2` in grid cells (at least 1: single cells are always tested)."""
        return max(1, int(math.floor(self.low_cluster_max_m2 / (self.grid_m * self.grid_m) + 1e-9)))

    def alphas_m(self) -> np.ndarray:
        """The pyramid, top first: `alpha_k = alpha_max - (k - 1) * alpha_step >= alpha_min` (Eq. 1).

        Returns float64 `(L,)` [m], strictly decreasing; `alpha_top_m` first when set.
        """
        count = int(math.floor((self.alpha_max_m - self.min_alpha_m) / self.alpha_step_m + 1e-9)) + 1
        alphas = self.alpha_max_m - self.alpha_step_m * np.arange(count, dtype=np.float64)
        if self.alpha_top_m is not None:
            alphas = np.concatenate([[float(self.alpha_top_m)], alphas])
        return alphas


class Params(params.Params):
    """Traced MASF thresholds (float32 scalars).

    Attributes:
      st: slope threshold ST = tan(theta) of Eq. 2 [-].
      ft_m: final threshold FT [m]: the offset of Eq. 2 and the last whole-cloud test.
    """

    ranges = RANGES

    st: Float[Array, ""] = param(0.05)
    ft_m: Float[Array, ""] = param(0.5)



# Cao et al. (2024), Table 3 (alpha_max [m], alpha_step [m], ST) for the 11 ISPRS samples we
# have; FT 0.5 m and grid 1 m throughout. samp42's top layer uses alpha = 90 m (Sec. 3.3.1).
PAPER_TABLE3: dict[str, tuple[float, float, float]] = {
    "samp12": (25.0, 1.0, 0.05), "samp21": (20.0, 2.0, 0.05), "samp22": (25.0, 1.0, 0.10),
    "samp24": (10.0, 1.0, 0.10), "samp31": (25.0, 2.0, 0.01), "samp41": (25.0, 2.0, 0.05),
    "samp42": (20.0, 9.0, 0.10), "samp51": (25.0, 4.0, 0.05), "samp52": (20.0, 1.0, 0.05),
    "samp54": (20.0, 9.0, 0.05), "samp71": (15.0, 2.0, 0.05),
}


def _paper_preset(sample: str) -> dict[str, float | str | None]:
    """The paper's values for one sample, with its readings: buffer heights from the top layer,
    no mirror test."""
    alpha_max, step, st = PAPER_TABLE3[sample]
    preset: dict[str, float | str | None] = {"alpha_max_m": alpha_max, "alpha_step_m": step, "st": st, "ft_m": 0.5,
                                             "buffer_heights": "top", "mirror_max_m": None}
    if sample == "samp42":
        preset["alpha_top_m"] = 90.0
    return preset


# SPEC section 4, fixed before measuring. Values in metres (st is rise over run).
PRESETS: dict[str, dict[str, float | str | None]] = {
    "flat": {"alpha_max_m": 25.0, "alpha_step_m": 2.0, "st": 0.02},
    "urban": {"alpha_max_m": 25.0, "alpha_step_m": 1.0, "st": 0.05},
    "steep": {"alpha_max_m": 10.0, "alpha_step_m": 1.0, "st": 0.15},
    **{f"paper-{name}": _paper_preset(name) for name in PAPER_TABLE3},
}


# Low outliers hidden before the preprocessing (`gfjax.low_outliers`): on the training files
# (`experiments/results/low_outliers_methods.md`) samp41's type I falls from 9.9 % to 6.8 %, no file
# gets worse by more than 0.01 % total error. A cruder detector that hid part of samp41's outlier
# patches and much ground made it worse (type I 45.8 %): with the deep outliers gone but shallower
# ones left, the pit test among the seeds (`pit_slope`) took a valley floor for a pit of outliers.
HIDES_LOW_OUTLIERS = True


def adapt(terrain: adaptive.Terrain) -> dict[str, float | bool]:
    """MASF's values that follow the cloud (`gfjax.adaptive`): the 1 m grid, or the coarser
    `adaptive.cost_cell_m` of a cloud spread thinner than a point per 64 m² (no labelled file
    is: the grids tried on them are in `experiments/results/adaptive_rules_masf.md`); a call
    that settles them also drops ground spikes (`adaptive.finish`). A coarser grid scales the
    alpha pyramid with it (alpha_min is twice the grid), so it keeps its layers. Such a call
    hides the low outliers first (`HIDES_LOW_OUTLIERS`), so the preprocessing's own
    neighbourhood test is left out (`Config.neighbour_test`; on the IGN forest at 0.06
    points/m² it took 2,000 of its 4,820 ground points for low outliers:
    `experiments/results/masf_accuracy.md`)."""
    chosen: dict[str, float | bool] = {"neighbour_test": not HIDES_LOW_OUTLIERS}
    cell, fixed = adaptive.cost_cell_m(terrain), Config()
    if cell > fixed.grid_m:
        scale = cell / fixed.grid_m
        chosen.update(grid_m=cell, alpha_max_m=fixed.alpha_max_m * scale, alpha_step_m=fixed.alpha_step_m * scale)
    return chosen
