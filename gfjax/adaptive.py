"""Defaults that follow the cloud: its statistics, each method's rules on them, a spike guard.

A method's fixed defaults (`Config()`, `Params()`) were chosen on the ISPRS samples, at about
1 point/m²; on a thinned survey of 0.1 points/m² a 1 m raster is mostly empty and its minimum
surface is the canopy. So the values that depend on the data are set from the cloud itself:

- `measure(xyz_m, last_xyz_m) -> Terrain`: the point spacing over the area the points cover
  (of all returns and of the last ones), and the slopes of a coarse minimum surface with the
  objects eroded away (numpy and one scipy filter; no labels). `measure_chunks`: the same
  `Terrain` of points read a chunk at a time (a survey's file from disk:
  `gfjax.survey.survey_terrain`), holding a chunk and the measuring grids, never the cloud;
  `measure` is it on one chunk. `combine` joins a survey's files.
- Each method package's `adapt(terrain) -> dict` (`gfjax.smrf.adapt`, `gfjax.pmf.adapt`, ...):
  the values of its `Config` / `Params` fields that follow from the terrain, each a documented
  function of it, chosen on the training files of `experiments/common.LABELLED` only
  (`experiments/adaptive_rules.py`; `experiments/corpus_eval.py` scores every labelled file).
- `settle_cloud` / `settle_terrain`: a method's `Config` / `Params` with the rules' values,
  except the fields in `fixed` (a user's `--set`, `--params` or preset values, which always
  win), and what was chosen (`Settled`: `gfjax filter -v`, `Result.settled`).
- `run`: the one sequence of a run whose values followed the cloud: the method's low outliers
  hidden from it first (`gfjax.low_outliers`, for a method that asks: `Method.hides_low_outliers`)
  and labelled non-ground, the method run, then ground spikes dropped (`finish`,
  `gfjax.spikes`). The `follows` decorator and `gfjax filter` (`MethodSetup.filter`) both call it,
  so a Python call, the command line and a survey's window get the same labels.
- `follows`: the decorator that gives a method's `filter` all of this when it is called
  without a `config`.

A caller that wants the fixed values passes them: `filter(cloud, config=Config())` uses
`Config()` as it is, with no pre-step and no spike guard; `--preset fixed` does the same on the
command line.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import numpy as np

from gfjax import limits, low_outliers, spikes
from gfjax.errors import InputError, SettingError
from gfjax.io.cloud import CloudView, Frame

RETURNS = ("all", "last")

__all__ = ["Terrain", "measure", "measure_chunks", "cloud_parts", "Chunk", "Parts", "follows", "run", "finish", "hide", "Hidden", "raster_cell_m", "settle_cloud", "given_params", "measure_cloud", "combine", "settle_terrain", "Settled", "show", "FIXED_PRESET"]

# The preset name that keeps a method's fixed defaults (no rule applied).
FIXED_PRESET = "fixed"
_POINTS_PER_COVER_CELL = 16      # mean points per cell of the cover grid, so cells are empty for want of data,
_MIN_COVER_CELL_M = 2.0          # not by chance
_PART_POINTS = 1 << 18          # used points a slice of one cloud holds at least (`cloud_parts`)
_COVER_PASSES = 4                # the cover cell from the box's density, then three times from the area's
_OBJECT_M = 30.0                 # objects narrower than this are taken off the minimum surface before slopes
_EROSION_PERCENTILE = 10         # ... by this percentile of a square of that side
_FILTER_BLOCK = 1 << 22          # window values a block of `_percentile_filter` holds at once
_SURFACE_RASTERS = 6             # float64 rasters `_surface` holds beside the minimum surfaces, at most
_SLOPE_CELLS_PER_SPACING = 4     # the slope grid's cell, in point spacings: a few points per cell, so its
_MIN_SLOPE_CELL_M = 5.0          # minimum is mostly ground under canopy


# The 1 m raster cell of SMRF and PMF holds up to the ISPRS samples' 2.4 m spacing (empty cells
# are filled); beyond it, where under canopy one cell in ten or more holds a last return, the
# minimum surface is mostly canopy. Chosen on the training files of `experiments.common.LABELLED`
# (on the IGN forest at 0.06 points/m², last returns 5.1 m apart, SMRF's type I falls from 56 %
# at 1 m to 3.6 % at 5 m; `experiments/results/adaptive_rules_pmf.md` for PMF).
COARSE_SPACING_M = 2.5
# The coarsest cell the rule sets: a third of SMRF's 18 m window, so its opening still grows
# over three radii. Scattered points farther apart are no surface a raster can model.
MAX_CELL_M = 6.0


# The most cells a rule gives a raster per point over the area the points cover. A cloud spread
# so thinly that a finer cell would give more (under one point per 64 m² at 1 m: a few hundred
# points over square kilometres) gets the coarser cell, so its rasters cost what its points
# cost; there is no surface to model at that spacing anyway. No labelled file comes near: the
# sparsest has 16 m² a point.
CELLS_PER_POINT = 64


def cost_cell_m(terrain: Terrain) -> float:
    """The finest cell [m] whose raster over the points' area holds at most `CELLS_PER_POINT`
    cells a point, rounded up to 0.5 m; 0 for fewer than `_POINTS_PER_COVER_CELL` points, whose
    area is not measured (a few points cost little, and points far apart are filtered as
    groups: `gfjax.tiling.groups`)."""
    if terrain.n_points < _POINTS_PER_COVER_CELL:
        return 0.0
    return math.ceil(math.sqrt(terrain.area_m2 / (CELLS_PER_POINT * terrain.n_points)) / 0.5) * 0.5


def raster_cell_m(terrain: Terrain) -> float:
    """A morphological filter's raster cell [m] for a cloud: 1 m until the last returns lie
    more than `COARSE_SPACING_M` apart, then their spacing rounded down to 0.5 m, at most
    `MAX_CELL_M`; never finer than `cost_cell_m`."""
    spacing = terrain.last_spacing_m
    cell = 1.0 if spacing <= COARSE_SPACING_M else min(MAX_CELL_M, math.floor(spacing / 0.5) * 0.5)
    return max(cell, cost_cell_m(terrain))


class Terrain(NamedTuple):
    """What the rules know of a cloud (all from the points the method uses, metres).

    Attributes:
      n_points: points measured.
      area_m2: area the points cover: the occupied cells of a grid of about 16 points a cell.
      spacing_m: mean point spacing, `sqrt(area_m2 / n_points)` (1 / sqrt(density)).
      last_spacing_m: the same of the last returns alone (what reaches the ground under
        canopy; `spacing_m` where every return is a last one).
      slope_cell_m: cell of the coarse minimum surface the slopes are measured on.
      slope_p50, slope_p90: median and 90th percentile of that surface's slope (rise over
        run) over its cells with four neighbours, once objects up to 30 m wide are eroded away
        (`_ground_only`); 0 for a cloud of fewer than 2 × 2 cells.
      relief_m: 98th minus 2nd percentile of that surface [m].
    """

    n_points: int
    area_m2: float
    spacing_m: float
    last_spacing_m: float
    slope_cell_m: float
    slope_p50: float
    slope_p90: float
    relief_m: float

    def describe(self) -> str:
        """One line for `gfjax filter -v`."""
        return (f"{self.n_points:,} points over {self.area_m2:,.0f} m², spacing {self.spacing_m:.2f} m "
                f"(last returns {self.last_spacing_m:.2f} m); "
                f"ground slope (minimum surface, {self.slope_cell_m:.1f} m cells) median {self.slope_p50:.2f}, "
                f"90th percentile {self.slope_p90:.2f}; relief {self.relief_m:.1f} m")


def _shape(box: tuple[np.ndarray, np.ndarray], cell_m: float) -> tuple[int, int]:
    """`(rows, columns)` of a grid of `cell_m` from the corner `box[0]` (float64 `(2,)`: the
    points' minimum x, y) that holds the `box` (`_box`)."""
    lo, hi = box
    return int((hi[1] - lo[1]) / cell_m) + 1, int((hi[0] - lo[0]) / cell_m) + 1


def _flat_cells(dx: np.ndarray, dy: np.ndarray, cell_m: float, shape: tuple[int, int]) -> np.ndarray:
    """Flat cell index int64 `(n,)` of points at offsets `dx`, `dy` (float64 `(n,)`, >= 0) from
    the corner of a grid of `cell_m` and `shape` (`_shape`). Column by column: numpy runs
    `(n, 2)` arithmetic through an inner loop of two elements, several times slower."""
    col = (dx / cell_m).astype(np.int64)                   # >= 0: truncation is the floor
    np.minimum(col, shape[1] - 1, out=col)                 # rounding at the far edge
    row = (dy / cell_m).astype(np.int64)
    np.minimum(row, shape[0] - 1, out=row)
    row *= shape[1]
    row += col
    return row


def _box(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`(lo, hi)`: minimum and maximum x, y of points, float64 `(2,)` each."""
    return np.array([x.min(), y.min()]), np.array([x.max(), y.max()])


def _ground_only(z_min: np.ndarray, cell_m: float) -> np.ndarray:
    """The minimum surface `(h, w)` (+inf where empty) eroded by a square of about
    `_OBJECT_M`: an erosion shifts a slope but keeps its gradient, and takes away the buildings
    and tree crowns narrower than the square, whose walls would read as steep ground. The
    square's 10th percentile, not its minimum, so a low outlier (multipath) does not spread."""
    size = max(3, 2 * math.ceil(_OBJECT_M / (2 * cell_m)) + 1)
    eroded = _percentile_filter(z_min, _EROSION_PERCENTILE, size)
    return np.where(np.isfinite(z_min), eroded, np.inf)


def _percentile_filter(z: np.ndarray, percentile: int, size: int) -> np.ndarray:
    """`scipy.ndimage.percentile_filter(z, percentile, size=size, mode="nearest")` of a float
    raster `(h, w)` without NaN, for an odd `size`: the same rank of each square window (edges
    repeated), taken by `np.partition` a block of rows at a time. A selection, so the values
    are scipy's exactly (`tests/test_adaptive.py`); scipy.ndimage itself takes 0.05 s to
    import, a tenth of what `measure` then costs on a million points."""
    count = size * size
    rank = int(float(count) * percentile / 100.0)          # scipy's rank of a percentile
    windows = np.lib.stride_tricks.sliding_window_view(np.pad(z, size // 2, mode="edge"), (size, size))
    out = np.empty_like(z)
    rows = max(1, _FILTER_BLOCK // (z.shape[1] * count))
    for top in range(0, z.shape[0], rows):
        block = windows[top:top + rows].reshape(-1, count)
        out[top:top + rows] = np.partition(block, rank, axis=1)[:, rank].reshape(-1, z.shape[1])
    return out


# A chunk of the points `measure_chunks` reads: the x, y, z columns of the points a method uses
# and the x, y columns of their last returns (float64 `(k,)` and `(j,)` each; either may be empty).
Chunk = tuple[tuple[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def measure(xyz_m: np.ndarray, last_xyz_m: np.ndarray | None = None) -> Terrain:
    """The statistics of `Terrain` for points `(n, 3)` [m] (float; the points a method uses)
    and their last returns `(k, 3)` (None or empty: the same points): `measure_chunks` of one cloud
    (`cloud_parts`).

    Raises:
      ValueError: fewer than one point.
    """
    xyz = np.asarray(xyz_m, dtype=np.float64)
    used = tuple(np.ascontiguousarray(xyz[:, j]) for j in range(3))
    last_xy = (np.empty(0), np.empty(0))
    if last_xyz_m is not None:
        last = np.asarray(last_xyz_m, dtype=np.float64)
        last_xy = (np.ascontiguousarray(last[:, 0]), np.ascontiguousarray(last[:, 1]))
    terrain = measure_chunks(cloud_parts(used, last_xy))
    if terrain is None:
        raise ValueError("measure needs at least one point")
    return terrain


# Where the chunks come from: parts read anew at each call, side by side (a survey's files, a
# cloud's slices: `cloud_parts`).
Parts = Sequence[Callable[[], Iterable[Chunk]]]


def cloud_parts(used: tuple[np.ndarray, np.ndarray, np.ndarray], last_xy: tuple[np.ndarray, np.ndarray], *,
                workers: int | None = None) -> list[Callable[[], list[Chunk]]]:
    """One cloud in memory as `measure_chunks` parts: its used points' columns `used` and its
    last returns' `last_xy` (float64 `(n,)`, `(k,)`) cut into slices (views) of at least
    `_PART_POINTS` used points, at most one per worker (`limits.processors`)."""
    workers = limits.processors() if workers is None else workers
    count = max(1, min(workers, len(used[0]) // _PART_POINTS))

    def cut(columns: tuple[np.ndarray, ...]) -> list[tuple[np.ndarray, ...]]:
        edges = np.linspace(0, len(columns[0]), count + 1).astype(np.int64)
        return [tuple(c[a:b] for c in columns) for a, b in zip(edges[:-1], edges[1:])]

    return [lambda u=u, v=v: [(u, v)] for u, v in zip(cut(used), cut(last_xy))]


def measure_chunks(parts: Parts, *, workers: int | None = None, name: str = "the points") -> Terrain | None:
    """`measure` of points read a chunk at a time from `parts` (a survey's files, a cloud's
    slices: each `part()` yields its `Chunk`s anew at each call), so memory holds a chunk a
    worker and a few grids of about a sixteenth as many cells as points a worker, never the
    whole cloud; None when no point is used. The parts are read side by side on `workers`
    threads (default: the processors, `limits.processors`; numpy's work on a chunk leaves the
    interpreter free). The statistics are `measure`'s of the chunks' points joined, exactly:
    each grid (the box, the occupied cells of each cover pass, the minimum per slope cell) is
    a union or a minimum over the chunks, whatever their order, and each pass's cell follows
    from the previous pass's grid, so every part is read `_COVER_PASSES + 2` times (a file on
    disk is read again, never held). The last returns' spacing is that of every point where
    none or all of them are last.

    Raises:
      InputError: a grid over the points' box would not fit the memory budget: groups of
        points far apart, named `name` in the message (`_check_grid`).
    """
    workers = min(limits.processors() if workers is None else workers, len(parts))
    if workers <= 1:
        return _measured(parts, _Threads(1, map), name)
    with ThreadPoolExecutor(workers, thread_name_prefix="gfjax-measure") as pool:
        return _measured(parts, _Threads(workers, pool.map), name)


class _Threads(NamedTuple):
    """Where `measure_chunks`' passes run: `count` threads and the `map` that runs on them."""

    count: int
    map: Callable


def _measured(parts: Parts, threads: _Threads, name: str) -> Terrain | None:
    """`measure_chunks` with its passes on `threads`."""
    n, box, n_last, last_box = _extents(parts, threads)
    if n == 0:
        return None
    with_last = 0 < n_last < n
    area, spacing = _spacing(parts, threads, n, box, n_last, last_box if with_last else None, name)
    slope_cell = max(_MIN_SLOPE_CELL_M, _SLOPE_CELLS_PER_SPACING * spacing[0])
    lo, shape = box[0], _shape(box, slope_cell)
    # a minimum surface a thread, and the erosion's few rasters of it
    _check_grid(name, box, slope_cell, shape, 8.0 * (threads.count + _SURFACE_RASTERS))

    def lowest(chunks: Iterable[Chunk]) -> np.ndarray:
        z_min = np.full(shape[0] * shape[1], np.inf)
        for (x, y, z), _ in chunks:
            np.minimum.at(z_min, _flat_cells(x - lo[0], y - lo[1], slope_cell, shape), z)
        return z_min

    z_min = functools.reduce(np.minimum, _side_by_side(parts, threads, lowest))
    p50, p90, relief = _surface(z_min.reshape(shape), slope_cell)
    return Terrain(n_points=n, area_m2=float(area), spacing_m=spacing[0], last_spacing_m=spacing[-1],
                   slope_cell_m=slope_cell, slope_p50=p50, slope_p90=p90, relief_m=relief)


def _side_by_side(parts: Parts, threads: _Threads, fold: Callable[[Iterator[Chunk]], Any]) -> list[Any]:
    """`fold(chunks)` of the parts dealt to each of the threads in turn (each thread folds the
    chunks of its parts, one after another, into one value: memory holds one fold's grids a
    thread, however many parts): the values, one a thread."""
    groups = [parts[k::threads.count] for k in range(threads.count)]

    def folded(group: Parts) -> Any:
        return fold(chunk for part in group for chunk in part())

    return list(threads.map(folded, groups))


def _surface(z_min: np.ndarray, slope_cell: float) -> tuple[float, float, float]:
    """`(slope_p50, slope_p90, relief_m)` of `Terrain` from the minimum surface `(h, w)` [m]
    (+inf where a cell holds no point) on cells of `slope_cell` [m]."""
    z_min = _ground_only(z_min, slope_cell)
    filled = np.isfinite(z_min)
    slopes = np.empty(0)
    if z_min.shape[0] >= 2 and z_min.shape[1] >= 2:
        # central differences where a cell and its four neighbours hold points
        core = filled[1:-1, 1:-1] & filled[:-2, 1:-1] & filled[2:, 1:-1] & filled[1:-1, :-2] & filled[1:-1, 2:]
        with np.errstate(invalid="ignore"):
            dz_dy = (z_min[2:, 1:-1] - z_min[:-2, 1:-1]) / (2 * slope_cell)
            dz_dx = (z_min[1:-1, 2:] - z_min[1:-1, :-2]) / (2 * slope_cell)
        slopes = np.hypot(dz_dx, dz_dy)[core]
        if slopes.size == 0:       # two rows or columns: forward differences
            right = filled[:, :-1] & filled[:, 1:]
            down = filled[:-1, :] & filled[1:, :]
            with np.errstate(invalid="ignore"):
                steps = [np.abs(np.diff(z_min, axis=1))[right], np.abs(np.diff(z_min, axis=0))[down]]
            slopes = np.concatenate(steps) / slope_cell
    p50, p90 = (float(v) for v in np.percentile(slopes, [50, 90])) if slopes.size else (0.0, 0.0)
    lows = z_min[filled]
    return p50, p90, float(np.percentile(lows, 98) - np.percentile(lows, 2))


Box = tuple[np.ndarray, np.ndarray]


def _extents(parts: Parts, threads: _Threads) -> tuple[int, Box, int, Box]:
    """`(n, box, n_last, last_box)`: the count and `_box` of the used points and of their last
    returns over every chunk (a box of `inf`, `-inf` where there is none)."""
    def fold(chunks: Iterable[Chunk]) -> tuple[list[int], list[Box]]:
        counts = [0, 0]
        boxes = [(np.full(2, np.inf), np.full(2, -np.inf)) for _ in range(2)]
        for used, last in chunks:
            for i, (x, y) in enumerate((used[:2], last)):
                if len(x):
                    counts[i] += len(x)
                    lo, hi = _box(x, y)
                    np.minimum(boxes[i][0], lo, out=boxes[i][0])
                    np.maximum(boxes[i][1], hi, out=boxes[i][1])
        return counts, boxes

    folds = _side_by_side(parts, threads, fold)
    counts = [sum(c[i] for c, _ in folds) for i in range(2)]
    boxes = [(functools.reduce(np.minimum, [b[i][0] for _, b in folds]),
              functools.reduce(np.maximum, [b[i][1] for _, b in folds])) for i in range(2)]
    return counts[0], boxes[0], counts[1], boxes[1]


def _spacing(parts: Parts, threads: _Threads, n: int, box: Box, n_last: int,
             last_box: Box | None, name: str = "the points") -> tuple[float, list[float]]:
    """`(area_m2, spacings_m)` of the used points (`n` >= 1 of them, their `box`) [m]
    (`Terrain`): their area, and the spacing of them and, where `last_box` is given, of their
    last returns (`n_last` in `last_box`) after it.

    The cover grid's cell is set from the density, which is what is measured: start from the
    box's, then the covered area's, a few times over, so a stray point kilometres away or an
    L-shaped survey does not make the cells (and so the area) as large as the box. Each pass
    reads every chunk once and keeps one occupancy grid per selection (a worker).
    """
    sets = [(0, n, box)] + ([] if last_box is None else [(1, n_last, last_box)])
    areas = [float(np.maximum(b[1] - b[0], 1.0).prod()) for _, _, b in sets]
    for _ in range(_COVER_PASSES):
        grids = []
        for (_, count, grid_box), area in zip(sets, areas):
            cover_m = max(_MIN_COVER_CELL_M, math.sqrt(_POINTS_PER_COVER_CELL * area / count))
            grids.append((cover_m, _shape(grid_box, cover_m)))
            _check_grid(name, grid_box, cover_m, grids[-1][1], float(threads.count * len(sets)))

        def fold(chunks: Iterable[Chunk], grids=grids) -> list[np.ndarray]:
            occupied = [np.zeros(shape[0] * shape[1], dtype=bool) for _, shape in grids]
            for chunk in chunks:
                for (i, _, (lo, _)), (cover_m, shape), cells in zip(sets, grids, occupied):
                    x, y = chunk[i][:2]
                    cells[_flat_cells(x - lo[0], y - lo[1], cover_m, shape)] = True
            return occupied

        folds = _side_by_side(parts, threads, fold)
        occupied = [functools.reduce(np.logical_or, [f[k] for f in folds]) for k in range(len(sets))]
        areas = [np.count_nonzero(cells) * cover_m * cover_m for (cover_m, _), cells in zip(grids, occupied)]
    return areas[0], [math.sqrt(area / count) for (_, count, _), area in zip(sets, areas)]


def _check_grid(name: str, box: Box, cell_m: float, shape: tuple[int, int], bytes_per_cell: float) -> None:
    """`InputError` when a measuring grid of `shape` cells of `cell_m` over `box`, at
    `bytes_per_cell`, would not fit the memory budget (`limits`): its points lie in groups far
    apart (files of distant places filtered as one survey), whose box is mostly empty."""
    need = float(shape[0]) * float(shape[1]) * bytes_per_cell
    budget = limits.memory_budget_bytes()
    if need <= budget:
        return
    span_km = (np.asarray(box[1], np.float64) - np.asarray(box[0], np.float64)) / 1000.0
    raise InputError(f"{name}: spread over {span_km[0]:,.1f} x {span_km[1]:,.1f} km, so measuring their terrain "
                     f"takes a grid of {shape[0]:,} x {shape[1]:,} cells of {cell_m:.3g} m, about "
                     f"{limits.byte_size(need)}, more than the memory budget of {limits.byte_size(budget)} "
                     f"(set {limits.BUDGET_ENV} to change it); filter places far apart separately (gfjax filter "
                     "--independent, or one survey per place)")


def combine(terrains: Iterable[Terrain]) -> Terrain:
    """One `Terrain` of several clouds side by side (a survey's files): areas and points add,
    spacings follow from their sums, slopes and relief are the medians of the clouds', weighted
    by points. Raises ValueError for none."""
    parts = list(terrains)
    if not parts:
        raise ValueError("combine needs at least one terrain")
    if len(parts) == 1:
        return parts[0]
    n = sum(t.n_points for t in parts)
    area = sum(t.area_m2 for t in parts)
    n_last = sum(t.n_points * (t.spacing_m / t.last_spacing_m) ** 2 for t in parts)   # area / spacing²

    def median(key: str) -> float:
        values = np.array([getattr(t, key) for t in parts])
        weights = np.array([t.n_points for t in parts], dtype=np.float64)
        order = np.argsort(values)
        cumulative = np.cumsum(weights[order])
        return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])

    return Terrain(n_points=n, area_m2=area, spacing_m=math.sqrt(area / n), last_spacing_m=math.sqrt(area / n_last),
                   slope_cell_m=median("slope_cell_m"), slope_p50=median("slope_p50"),
                   slope_p90=median("slope_p90"), relief_m=median("relief_m"))


def settle_terrain(rule: Callable[[Terrain], dict[str, Any]] | None, terrain: Terrain, config: Any, params: Any, *,
                   fixed: Iterable[str] = ()) -> Settled:
    """`config` and `params` with the values `rule(terrain)` gives, but for the fields in
    `fixed` (a user's, kept as they are); what was chosen and the terrain in `Settled`. A
    rule's value is checked by the dataclass like any other (`SettingError`)."""
    if rule is None:
        return Settled(config, params, {}, None)
    keep = set(fixed)
    chosen = {k: v for k, v in rule(terrain).items() if k not in keep}
    config_fields = {f.name for f in dataclasses.fields(config)}
    on_config = {k: v for k, v in chosen.items() if k in config_fields}
    on_params = {k: v for k, v in chosen.items() if k not in config_fields}
    try:
        if on_config:
            config = dataclasses.replace(config, **on_config)
        if on_params:
            if params is None:
                raise ValueError(f"rule sets {sorted(on_params)} but the method has no Params")
            params = dataclasses.replace(params, **on_params)
    except SettingError as err:
        given = [k for k in err.keys if k in keep]
        if not given:
            raise
        # a user's value against one the cloud chose: the user says which to change
        picked = show({k: v for k, v in chosen.items() if k in err.keys})
        raise InputError(f"{err}: {', '.join(given)} given, {picked or 'the rest'} chosen from the cloud; "
                         "set both (--set), or --preset fixed") from None
    return Settled(config, params, chosen, terrain)


class Settled(NamedTuple):
    """A method's settings for one cloud: `config`, `params`, and `chosen` (field -> value
    the rules set; the fields kept fixed are not in it) with the `terrain` they came from;
    after a run (`run`), `low_outliers`: how many points were hidden from the method as low
    outliers (None: the method does not hide them)."""

    config: Any
    params: Any
    chosen: dict[str, Any]
    terrain: Terrain | None
    low_outliers: int | None = None

    def describe(self) -> str:
        """Lines for `gfjax filter -v`: the terrain, then each value the rules chose."""
        if self.terrain is None:
            return "fixed settings (no rule applied)"
        return f"terrain: {self.terrain.describe()}\n" + "\n".join(self.choices())

    def choices(self) -> list[str]:
        """`describe`'s lines after the terrain's: the values chosen, the low outliers hidden."""
        values = show(self.chosen) or "none (every value fixed)"
        hidden = [] if self.low_outliers is None else [f"low outliers hidden from it: {self.low_outliers:,}"]
        return [f"chosen from it: {values}", *hidden]


def show(values: dict[str, Any]) -> str:
    """`name=value, ...` of settings for `gfjax filter -v` (floats to 4 significant digits)."""
    return ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items())


def follows(rule: Callable[[Terrain], dict[str, Any]], config_type: type, params_type: type | None, *,
            hides_low_outliers: bool = False):
    """Decorate a method's `filter(cloud, *, config=None, params=None, returns="all", ...)` so
    that a call without a `config` settles the method's values on the cloud (`rule`: the
    method's `adapt`; a given `params` is kept whole) and runs the method as `run` does: its low
    outliers hidden first when `hides_low_outliers` (the method's `Method.hides_low_outliers`),
    ground spikes dropped after. A call with a `config` runs it as given: nothing follows the data.
    The decorated filter also takes `terrain`: the cloud's `measure_cloud(cloud, returns)` when
    the caller has it already (several methods on one cloud, the vote), so it is not measured again.
    """
    def wrap(filter_fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(filter_fn)
        def filter(cloud, *, config=None, params=None, returns: str = "all", terrain: Terrain | None = None,  # noqa: A001
                   **kwargs):
            settled = None
            if config is None and isinstance(cloud, CloudView) and returns in RETURNS:
                params, fixed = given_params(params, params_type)
                settled = settle_cloud(rule, cloud, config_type(), params, fixed=fixed, returns=returns,
                                       terrain=terrain)
                if settled.terrain is None:                 # no point used: nothing to follow
                    settled = None
                else:
                    config, params = settled.config, settled.params
            return run(filter_fn, cloud, settled, config=config, params=params, returns=returns,
                       hides_low_outliers=hides_low_outliers, **kwargs)
        return filter
    return wrap


def run(filter_fn: Callable[..., Any], cloud: Any, settled: Settled | None, *, config: Any, params: Any,
        returns: str = "all", hides_low_outliers: bool = False, **kwargs) -> Any:
    """`filter_fn(cloud, config=config, params=params, returns=returns, **kwargs)` (a method's
    filter, a `gfjax.result.Result`), as a run whose values followed the data when `settled` has
    a terrain: the low outliers of the points it uses hidden from it first where
    `hides_low_outliers` (`hide`; they come out non-ground), its ground spikes dropped after
    (`finish`). With no terrain (fixed values: `--preset fixed`, a given `config`), the filter's
    result as it is."""
    if settled is None or settled.terrain is None:
        return filter_fn(cloud, config=config, params=params, returns=returns, **kwargs)
    low = hide(cloud, settled.terrain, returns=returns) if hides_low_outliers else None
    view = cloud if low is None else Hidden(cloud, low)
    result = filter_fn(view, config=config, params=params, returns=returns, **kwargs)
    if low is not None:
        result = result._replace(ground=np.asarray(result.ground, dtype=bool) & ~low)
    if hides_low_outliers:
        settled = settled._replace(low_outliers=0 if low is None else int(low.sum()))
    return finish(result, view, settled)         # a hidden point is no lower return under a ground point


def hide(cloud: Any, terrain: Terrain, *, returns: str = "all") -> np.ndarray | None:
    """The low outliers bool `(n,)` among `cloud`'s used points (`gfjax.low_outliers.detect`,
    cells of the terrain's last-return spacing laid from the cloud's frame, so a survey's window
    shares the whole survey's cells), or None when there is none."""
    frame: Frame | None = getattr(cloud, "frame", None)
    low = low_outliers.detect(cloud.xyz_m, cloud.filter_mask(returns), last_spacing_m=terrain.last_spacing_m,
                              origin_m=None if frame is None else frame.origin_m)
    return low if low.any() else None


class Hidden:
    """A `CloudView` of `cloud` with the points `hidden` (bool `(n,)`) left out of every
    `filter_mask`, as ignored points are: a method neither uses nor labels them."""

    def __init__(self, cloud: Any, hidden: np.ndarray):
        self.cloud, self.hidden = cloud, np.asarray(hidden, dtype=bool)
        self.name, self.frame = cloud.name, cloud.frame

    @property
    def xyz_m(self) -> np.ndarray:
        return self.cloud.xyz_m

    @property
    def n_points(self) -> int:
        return self.cloud.n_points

    def filter_mask(self, returns: str = "all") -> np.ndarray:
        return self.cloud.filter_mask(returns) & ~self.hidden


def finish(result: Any, cloud: Any, settled: Settled | None) -> Any:
    """`result` (a `gfjax.result.Result` on `cloud`) with `settled` attached, its ground points
    over lower returns and its ground spikes dropped (`gfjax.spikes.unstack`, `despike`), where
    the values followed the data (`settled` with a terrain); `result` itself otherwise."""
    if settled is None or settled.terrain is None:
        return result
    ground = spikes.guard(cloud.xyz_m, cloud.filter_mask("all"), np.asarray(result.ground, dtype=bool),
                          spacing_m=settled.terrain.spacing_m, slope_p90=settled.terrain.slope_p90)
    return result._replace(ground=ground, settled=settled)


def measure_cloud(cloud: Any, returns: str = "all") -> Terrain | None:
    """`measure` of a cloud's used points (`cloud.filter_mask(returns)`) and their last returns;
    None without a used point."""
    xyz = cloud.xyz_m
    use = cloud.filter_mask(returns)
    if not use.any():
        return None
    last = cloud.filter_mask("last")
    # column by column: (n, 3) rows gathered by a mask cost three times as much
    columns = [np.ascontiguousarray(xyz[:, j]) for j in range(3)]
    used = tuple(columns) if use.all() else tuple(c[use] for c in columns)
    last_xy = (columns[0][last], columns[1][last])
    return measure_chunks(cloud_parts(used, last_xy), name=getattr(cloud, "name", "the points"))


def given_params(params: Any, params_type: type | None) -> tuple[Any, list[str]]:
    """`(params, fixed)` for settling a caller's values: a given `params` kept whole (every
    field fixed), else the defaults (`params_type()`, None for a method without Params) with
    every field left to the data."""
    if params is not None:
        return params, [f.name for f in dataclasses.fields(params)]
    return (None if params_type is None else params_type()), []


def settle_cloud(rule: Callable[[Terrain], dict[str, Any]] | None, cloud: Any, config: Any, params: Any, *,
                 fixed: Iterable[str] = (), returns: str = "all", terrain: Terrain | None = None) -> Settled:
    """`settle_terrain` on the cloud's `terrain` (`measure_cloud(cloud, returns)` when not
    given); nothing changes (`Settled` without a terrain) without a rule or a used point."""
    if rule is None:
        return Settled(config, params, {}, None)
    terrain = measure_cloud(cloud, returns) if terrain is None else terrain
    if terrain is None:
        return Settled(config, params, {}, None)
    return settle_terrain(rule, terrain, config, params, fixed=fixed)
