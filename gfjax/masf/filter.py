"""`gfjax.masf.filter`: multiscale alpha shape filtering (MASF) of a whole cloud.

Cao, Wang, Du & Xi (2024), "A Multiscale Filtering Method for Airborne LiDAR Data Using
Modified 3D Alpha Shape", Remote Sens. 16:1443. Reads like the paper (Fig. 1):

1. preprocessing: one potential ground point per 1 m cell by the extended local minimum,
   low outliers removed (Sec. 2.1; `preprocess`);
2. the data pyramid: the modified 3D alpha shape of the potential ground points for
   `alpha_k = alpha_max - (k - 1) * alpha_step` (Eq. 1; Sec. 2.2-2.3; `alpha_shape`), all layers
   from one 3D Delaunay triangulation;
3. multiscale TIN densification with `DT_k = ST * alpha_k + FT` (Eq. 2; Sec. 2.4; `densify`).

Our readings where the paper is silent (R), beside SPEC section 4's:
- the bottom TIN of the "below" test is rasterised on the 1 m grid from the potential ground
  points themselves (one per cell; empty cells from the nearest occupied cell), sampled
  bilinearly; a centre outside the points' convex hull is never below;
- the neighbourhood low-outlier test compares a cell with every occupied cell of its 5x5
  window (`preprocess`), and a second test drops pits of low outliers from the top-layer seeds
  (`densify.low_seed_pits`): patches of multipath points that hold each other up;
- the pyramid stops at the last `alpha_k >= alpha_min` (alpha_min itself is not appended);
- a layer's rejected points are retested against the TIN holding the points just accepted, up
  to `layer_passes = 3` tests per layer (chosen by leave-one-out over 1 pass; the TIN grows
  by batch insertion, so a retest costs a fraction of a triangulation);
- the buffer points around the grid take their heights again before each layer from the
  ground found so far, carried along its slope (`Config.buffer_heights`): ground rising to the
  edge of the cloud otherwise stays above a TIN pinned at the top layer's height; a point near
  the TIN also joins it when its mirror image through the nearest vertex that joined by its own
  distance does (`Config.mirror_max_m`, Axelsson's mirror points), for ridges and terrace edges;
- alternatives kept as `Config` values, measured in `experiments/masf_isprs.py`:
  `layer_passes=1`, `retest_earlier`, `distance="nearest_facet"` (the paper's "nearest TIN facet").

Defined results on degenerate input (SPEC section 1): no used point -> no ground; when the
potential ground points span no tetrahedron (fewer than 4, or all coplanar or collinear) the
pyramid is skipped and every potential ground point seeds the TIN, so a flat tile, a single
point and fewer than 4 points come out all ground.
"""
from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from gfjax import adaptive, cache
from gfjax.errors import InputError
from gfjax.io.cloud import CloudView, Frame
from gfjax.masf import alpha_shape, preprocess, tin
from gfjax.masf import densify as densify_mod
from gfjax.masf.config import HIDES_LOW_OUTLIERS, Config, Params, adapt
from gfjax.result import Result
from gfjax.tiling import groups
from gfjax.tiling.checks import check_memory
from gfjax.tiling.driver import filter_groups

__all__ = ["filter", "Diagnostics", "filter_points", "Prepared", "prepare", "pyramid", "densify"]


class Diagnostics(NamedTuple):
    """What MASF computed on the way (host numpy).

    Attributes:
      potential_ground: int64 `(p,)` indices into the cloud of the potential ground points.
      alphas_m: float64 `(L,)` the pyramid, top first [m].
      layers: bool `(L, p)` layer membership of the potential ground points.
      added_per_layer: int64 `(L,)` potential ground points that joined the TIN per layer.
      bottom_z_m: float64 `(h, w)` rasterised bottom surface, absolute heights [m].
      neighbour_outliers: bool `(h, w)` cells whose point the neighbourhood test removed.
      occupied_cells: number of occupied grid cells (the unit of MASF's cost).
      n_triangles: triangles of the 3D Delaunay triangulation (0 when skipped).
      tin_rebuilds: TIN insertions that fell back to a full re-triangulation (ties; see `insertion`).
      origin_m: float64 `(3,)` the local origin; the grid's south-west corner is its x, y.
      seconds: dict stage -> wall-clock seconds.
    """

    potential_ground: np.ndarray
    alphas_m: np.ndarray
    layers: np.ndarray
    added_per_layer: np.ndarray
    bottom_z_m: np.ndarray
    neighbour_outliers: np.ndarray
    occupied_cells: int
    n_triangles: int
    tin_rebuilds: int
    origin_m: np.ndarray
    seconds: dict


class Prepared(NamedTuple):
    """What MASF computes before any alpha, ST or FT enters (Sec. 2.1 and the triangulation of
    Sec. 2.2): `prepare` reads only `grid_m`, `outlier_gap_m`, `neighbour_drop_m`,
    `low_cluster_max_m2` and `neighbour_test` of the config, so one preparation serves every pyramid and threshold
    (`gfjax.masf.tuning` searches them on it).

    Attributes:
      local: float64 `(n, 3)` the points less `origin` [m].
      origin: float64 `(3,)` the local origin; the grid's south-west corner is its x, y [m].
      pre: the potential ground points (`preprocess.potential_ground`).
      faces: the 3D Delaunay triangles of the potential ground points (`tin.delaunay_faces`),
        None when they span no tetrahedron.
      geometry: `alpha_shape.triangle_geometry` of `faces` (None with them).
      bottom_z, inside: the rasterised bottom surface (local heights [m]) and its hull mask.
      seconds: stage -> wall-clock seconds.
    """

    local: np.ndarray
    origin: np.ndarray
    pre: preprocess.Preprocessed
    faces: tuple | None
    geometry: tuple | None
    bottom_z: np.ndarray
    inside: np.ndarray
    seconds: dict

    @property
    def seed_xyz(self) -> np.ndarray:
        """float64 `(p, 3)` the potential ground points, local [m]."""
        return self.local[self.pre.index]


def prepare(xyz_m: np.ndarray, config: Config, frame: Frame | None = None, *,
            step: Callable[[str], None] = lambda name: None) -> Prepared:
    """Preprocess and triangulate once (steps 1 and the start of 2 of the module docstring).

    Args:
      xyz_m: float64 `(n, 3)` metres (any origin; the minimum corner is subtracted here).
      config: the settings (only those named in `Prepared` are read).
      frame: a survey's frame (`gfjax.io.cloud.Frame`): the grid's origin is then the corner of
        the survey's lattice cell that holds the minimum corner, so a window of the survey
        grids its points as the whole survey in one file does.
      step: told when each of its `PREPARE_STEPS` stages is done (a progress bar).
    """
    seconds: dict[str, float] = {}
    clock = time.perf_counter()
    xyz_m = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    origin = xyz_m.min(axis=0) if len(xyz_m) else np.zeros(3)
    if frame is not None and len(xyz_m):
        origin = frame.snap(origin, config.grid_m)
    local = xyz_m - origin
    pre = preprocess.potential_ground(local, grid_m=config.grid_m, outlier_gap_m=config.outlier_gap_m,
                                      neighbour_drop_m=config.neighbour_drop_m,
                                      max_cluster_cells=config.low_cluster_max_cells,
                                      neighbour_test=config.neighbour_test)
    seconds["preprocess"] = time.perf_counter() - clock
    step("preprocess")
    faces = geometry = None
    bottom_z, inside = np.zeros(pre.shape), np.zeros(pre.shape, bool)
    if len(pre.index):
        seed_xyz = local[pre.index]
        clock = time.perf_counter()
        faces = tin.delaunay_faces(seed_xyz)
        seconds["delaunay_3d"] = time.perf_counter() - clock
        step("triangulate")
        clock = time.perf_counter()
        bottom_z, inside = tin.bottom_surface(seed_xyz, pre.row, pre.col, pre.shape, cell_m=config.grid_m)
        if faces is not None:
            geometry = alpha_shape.triangle_geometry(seed_xyz, *faces)
        seconds["alpha_shape"] = time.perf_counter() - clock
    return Prepared(local, origin, pre, faces, geometry, bottom_z, inside, seconds)


def pyramid(prep: Prepared, config: Config) -> np.ndarray:
    """bool `(L, p)`: the layer of the data pyramid (`config.alphas_m()`, Eq. 1) each potential
    ground point belongs to; none when they span no tetrahedron (every one then seeds the TIN)."""
    alphas = config.alphas_m()
    if prep.faces is None:
        return np.zeros((len(alphas), len(prep.pre.index)), dtype=bool)
    return alpha_shape.layer_points(prep.seed_xyz, prep.faces[0], prep.geometry, prep.bottom_z, prep.inside,
                                    alphas, cell_m=config.grid_m, tol_m=config.empty_tol_m)


def densify(prep: Prepared, layers: np.ndarray, config: Config, params: Params, *,
            step: Callable[[str], None] = lambda name: None) -> densify_mod.Densified:
    """Multiscale TIN densification of the pyramid `layers` (`pyramid`) with `DT_k = ST *
    alpha_k + FT` (Eq. 2): ground of every point of `prep.local`."""
    return densify_mod.densify(prep.local, prep.pre.index, layers, config.alphas_m(), shape=prep.pre.shape,
                                 cell_m=config.grid_m, st=float(params.st), ft_m=float(params.ft_m),
                                 pit_drop_m=config.neighbour_drop_m, pit_slope=config.pit_slope,
                                 pit_cap_m=config.pit_cap_m, nearest_facet=config.distance == "nearest_facet",
                                 layer_passes=config.layer_passes, retest_earlier=config.retest_earlier,
                                 retriangulate=config.retriangulate, buffer_heights=config.buffer_heights,
                                 mirror_max_m=config.mirror_max_m, step=step)


# Stages `prepare` reports to its `step`; `filter_points` adds the pyramid and, through
# `densify`, one a layer.
PREPARE_STEPS = 2


def filter_points(xyz_m: np.ndarray, config: Config, params: Params, frame: Frame | None = None, *,
                  step: Callable[[str], None] = lambda name: None) -> tuple[np.ndarray, Diagnostics]:
    """MASF on an array of points: `prepare`, `pyramid`, `densify`.

    Args:
      xyz_m: float64 `(n, 3)` metres (any origin; the minimum corner is subtracted here).
      config, params: as for `filter`.
      frame: as for `prepare`.
      step: told when each stage is done: `PREPARE_STEPS + 1 + len(config.alphas_m())` calls
        (fewer for a cloud with no potential ground point).

    Returns:
      `(ground, diagnostics)`: bool `(n,)` and a `Diagnostics` (indices into `xyz_m`).
    """
    prep = prepare(xyz_m, config, frame, step=step)
    alphas = config.alphas_m()
    empty_diag = dict(potential_ground=prep.pre.index, alphas_m=alphas, occupied_cells=int(prep.pre.occupied.sum()),
                      neighbour_outliers=prep.pre.neighbour_outliers, origin_m=prep.origin, seconds=prep.seconds)
    if len(prep.pre.index) == 0:
        return np.zeros(len(prep.local), dtype=bool), Diagnostics(
            layers=np.zeros((len(alphas), 0), dtype=bool), added_per_layer=np.zeros(len(alphas), dtype=np.int64),
            bottom_z_m=np.zeros(prep.pre.shape), n_triangles=0, tin_rebuilds=0, **empty_diag)
    clock = time.perf_counter()
    layers = pyramid(prep, config)
    prep.seconds["alpha_shape"] += time.perf_counter() - clock
    step("alpha shapes")
    clock = time.perf_counter()
    result = densify(prep, layers, config, params, step=step)
    prep.seconds["densify"] = time.perf_counter() - clock
    return result.ground, Diagnostics(layers=layers, added_per_layer=result.added_per_layer,
                                          bottom_z_m=prep.bottom_z + prep.origin[2],
                                          n_triangles=0 if prep.faces is None else len(prep.faces[0]),
                                          tin_rebuilds=result.tin_rebuilds, **empty_diag)


@cache.persistent
@adaptive.follows(adapt, Config, Params, hides_low_outliers=HIDES_LOW_OUTLIERS)
def filter(cloud: CloudView, *, config: Config | None = None, params: Params | None = None,
           returns: str = "all", progress: bool = False) -> Result:
    """Classify ground points with MASF (Cao et al. 2024).

    Args:
      cloud: the point cloud; `cloud.xyz_m` (metres) is used, only `cloud.filter_mask(returns)`.
      config: static settings (`Config()`: alpha_max 25 m, step 2 m, grid 1 m).
      params: thresholds (`Params()`: ST 0.05, FT 0.5 m).
      returns: "all" or "last".
      progress: a progress bar over its stages and layers (stderr).

    Returns:
      `Result(ground, diagnostics)`: bool `(n,)` over the whole cloud (unused points False) and
      a `Diagnostics` whose `potential_ground` indexes the whole cloud (None when groups of
      points far apart were filtered one by one: `gfjax.tiling.driver.filter_groups`).

    Raises:
      InputError: a bad `returns`, `params` out of range, naming the option, or a grid over
        the memory budget (`gfjax.limits`).
    """
    config = Config() if config is None else config
    params = Params() if params is None else params
    try:
        used = cloud.filter_mask(returns)
    except ValueError as err:
        raise InputError(f"{cloud.name}: --returns: {err}") from None
    try:
        params.check()
    except ValueError as err:
        raise InputError(f"{cloud.name}: masf params: {err}") from None
    used_index = np.flatnonzero(used)
    if len(used_index):
        apart = filter_groups(cloud, used, functools.partial(filter, config=config, params=params),
                              gap_m=max(groups.GAP_M, config.reach_m), estimates=config.memory_estimates)
        if apart is not None:
            return apart
    xyz = cloud.xyz_m
    check_memory(cloud.name, config.memory_estimates, xyz[used_index, :2])
    with _stages_bar(progress, PREPARE_STEPS + 1 + len(config.alphas_m())) as step:
        ground_used, diagnostics = filter_points(xyz[used_index], config, params, cloud.frame, step=step)
    ground = np.zeros(cloud.n_points, dtype=bool)
    ground[used_index] = ground_used
    diagnostics = diagnostics._replace(potential_ground=used_index[diagnostics.potential_ground])
    return Result(ground=ground, diagnostics=diagnostics)


@contextlib.contextmanager
def _stages_bar(progress: bool, total: int):
    """A `step(name)` that advances a tqdm bar of `total` stages, or does nothing."""
    if not progress:
        yield lambda name: None
        return
    from tqdm.auto import tqdm

    with tqdm(total=total, desc="masf", unit="stage", leave=False) as bar:
        def step(name: str) -> None:
            bar.set_postfix_str(name, refresh=False)
            bar.update()
        yield step
