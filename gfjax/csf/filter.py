"""`gfjax.csf.filter`: the cloth simulation filter (Zhang et al. 2016) on a whole cloud.

Zhang, Qi, Wan, Wang, Xie, Wang & Yan (2016), "An easy-to-use airborne LiDAR data filtering
method based on cloth simulation", Remote Sensing 8(6):501. Follows the reference
implementation, the `cloth-simulation-filter` package (CSF.cpp `do_cloth`, `do_filtering`):

1. invert the cloud (`u = -z`) and lay a particle grid over its bounding box plus 2 cells;
2. each particle's surface height is its nearest point's `u` (gaps filled along scanlines);
3. drop the cloth under gravity, springs between neighbours, particles fixed where they hit
   the surface, until the iteration cap or the displacement stopping rule (`cloth.simulate`);
4. slope smoothing of movable particles next to fixed ones (`bSloopSmooth`);
5. a point is ground when `|cloth(x, y) - u| < class_threshold` (bilinear cloth).

The stages run as programs kept across processes (`gfjax.csf.programs`: `filter_points`, the
whole pipeline on one padded buffer under `jit` and `vmap`, and the programs `filter` runs,
the simulation a chunk at a time so that a progress bar moves between chunks).
"""
from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterable
from typing import NamedTuple

import jax
import numpy as np

from gfjax import adaptive, aot, cache
from gfjax.csf.config import ADAPTED, BUFFER_PX, HIDES_LOW_OUTLIERS, TREND_CELLS, Config, Params, adapt
from gfjax.csf.programs import (
    WARM_SIDES,
    Anchor,
    Surface,
    TileDiagnostics,
    canonical_grid,
    canonical_points,
    classify,
    drop_cloth_in_chunks,
    grid_shape,
    point_surface,
)
from gfjax.csf.trend import reach_m, trend_at
from gfjax.io.cloud import CloudView, Frame
from gfjax.result import Result
from gfjax.tiling import groups
from gfjax.tiling.checks import check_memory, checked_options
from gfjax.tiling.driver import filter_groups

__all__ = ["filter", "warm", "detrended", "framed", "survey_config", "survey_halo", "Diagnostics"]


class Diagnostics(NamedTuple):
    """What `filter` returns beside the labels (host numpy, row 0 = NORTH).

    Attributes:
      cloth_z: the final cloth as heights `(h, w)` [m, the cloud's vertical frame].
      surface_z: the nearest-point surface `(h, w)` [m].
      movable: bool `(h, w)`.
      steps: simulation steps run (<= `Config.iterations`).
      origin_m: float64 `(2,)`, x and y of particle `(j=0, i=0)` (the south-west one) [m].
      cell_m: particle spacing [m].
    """

    cloth_z: np.ndarray
    surface_z: np.ndarray
    movable: np.ndarray
    steps: int
    origin_m: np.ndarray
    cell_m: float


@cache.persistent
def warm(config: Config | None = None, params: Params | None = None, *, progress: bool = False,
         sides: tuple[int, ...] = WARM_SIDES) -> int:
    """Load, or compile and store (`gfjax.aot`), the cloth's programs `start_cloth`,
    `advance_cloth` and `finish_cloth` (those whose compile dominates a run: about 1 s, against
    0.1 s for `point_surface` and `classify`, which compile on first use) on every grid `(h, w)`
    of two `sides` (default: every canonical grid up to 512 particles a side, 25 grids), for
    `config` (default: the values a run without one settles on, `config.ADAPTED`). Nothing
    runs; nothing is kept when the program cache is off. Returns the number of grids prepared,
    three programs each (`gfjax warmup`)."""
    config, params = config or dataclasses.replace(Config(), **ADAPTED), params or Params()
    spec = jax.ShapeDtypeStruct

    def job(grid):
        surface = Surface(spec(grid, np.float32), spec(grid, np.bool_), spec(grid, np.bool_), spec((2,), np.float32),
                          spec((), np.float32))
        return lambda: drop_cloth_in_chunks(surface, params, config=config)     # under `aot.prefetching`

    return aot.warm_all([job((h, w)) for h in sides for w in sides], progress=progress, desc="csf programs")


def detrended(local: np.ndarray, use: np.ndarray, config: Config, trend_corner_m: np.ndarray | None = None):
    """Points `(n, 3)` in local metres as the cloth meets them: float32, less the terrain's trend
    where `config.trend_m` asks for it (`gfjax.csf.trend`, its first cell at `trend_corner_m`,
    local x, y [m]; None: the used points' own); and that trend (`height(xy)`, local metres) or
    None. The tuning (`gfjax.csf.tuning`) frames its samples with it too."""
    local = np.asarray(local, np.float64)
    if config.trend_m is None:
        return local.astype(np.float32), None
    trend = trend_at(local, use, window_m=config.trend_m, cell_m=config.trend_m / TREND_CELLS,
                     corner_m=trend_corner_m)
    local = local.copy()
    local[:, 2] -= trend(local[:, :2])
    return local.astype(np.float32), trend


def framed(lowest_m: np.ndarray, frame: Frame | None, config: Config) -> tuple[np.ndarray, np.ndarray | None]:
    """The local origin, float64 `(3,)` [m], of a cloud whose used points' lowest x, y, z are
    `lowest_m`, and the first cell of its trend in local x, y `(2,)` [m] (None: the points'
    own). On a survey's `frame` (a window), the survey's particle and trend lattices and its
    lowest z, as in one file of the whole survey; else the points' own corner."""
    if frame is None:
        return np.asarray(lowest_m, np.float64), None
    origin = frame.snap(lowest_m, config.cell_m)
    origin[2] = frame.origin_m[2]
    corner = None
    if config.trend_m is not None:
        corner = (frame.snap(lowest_m, config.trend_m / TREND_CELLS) - origin)[:2]
    return origin, corner


def survey_halo(config: Config) -> float:
    """The context [m] the trend needs (`gfjax.method.Method.survey_halo`): a window holding
    this much around its own points has the whole survey's trend under them (`reach_m`); 0
    without a trend."""
    return 0.0 if config.trend_m is None else reach_m(config.trend_m, config.trend_m / TREND_CELLS)


def survey_config(config: Config, clouds: Iterable[np.ndarray], frame: Frame | None = None) -> Config:
    """`config` with the cloth's start fixed once for a whole survey: `lowest_m`, the lowest
    height of its points above the trend, each file's trend laid on the survey's `frame`
    (`framed`) over the file and its halo, as the files joined into one lay it. A window's own
    lowest point is not the survey's, and the cloth's labels follow the height it falls from.
    `config` as it is without a trend or with `lowest_m` set.

    Args:
      config: the survey's settings.
      clouds: each file's points the cloth meets (used, low outliers hidden) and its halo's,
        float64 `(n_i, 3)` [m], and bool `(n_i,)` marking the file's own.
      frame: the survey's frame (`gfjax.io.cloud.Frame`), or None.
    """
    if config.trend_m is None or config.lowest_m is not None:
        return config
    lowest = math.inf
    for xyz, own in clouds:
        if own.any():
            xyz = np.asarray(xyz, np.float64)
            origin, corner = framed(xyz.min(axis=0), frame, config)
            local, _ = detrended(xyz - origin, np.ones(len(xyz), bool), config, corner)
            lowest = min(lowest, float(local[own, 2].min()))
    return config if lowest == math.inf else dataclasses.replace(config, lowest_m=lowest)


@cache.persistent
@adaptive.follows(adapt, Config, Params, hides_low_outliers=HIDES_LOW_OUTLIERS)
def filter(cloud: CloudView, *, config: Config | None = None, params: Params | None = None,
           returns: str = "all", progress: bool = False) -> Result:  # noqa: A001 (the package API name)
    """Classify a cloud's ground points with CSF (Zhang et al. 2016).

    Args:
      cloud: the point cloud (any units; filtered in metres).
      config: static settings (default `Config()`: 1 m cloth, rigidness 3, 500 iterations,
        slope smoothing on).
      params: traced settings (default `Params()`: class threshold 0.5 m, time step 0.65).
      returns: "all" or "last": which returns are filtered.
      progress: a progress bar over the cloth's simulation on stderr (tqdm; `TQDM_DISABLE`
        hides it): blocks of its pipelined loop run (`gfjax.csf.cloth`), of those a run to
        `config.iterations` steps takes, so the time left is the time to that cap, with the
        steps complete beside them; a cloth that settles sooner completes the bar where it
        stopped, which says at which step. False: nothing is drawn, and the simulation runs
        in one call. The labels are the same either way. A cloud filtered as groups far
        apart draws no bar (as DMF and MASF).

    Returns:
      `Result(ground, diagnostics)`: `ground` bool `(n,)`, False for ignored points;
      `diagnostics` a `Diagnostics` (None for a cloud with no usable point, and for one
      whose groups of points far apart were filtered one by one: `gfjax.tiling.driver.filter_groups`).
    """
    config, params, use = checked_options(cloud, config, params, returns, config_type=Config,
                                          params_type=Params, package="gfjax.csf")
    if not use.any():
        return Result(ground=np.zeros(cloud.n_points, bool), diagnostics=None)
    # a group far from the others is a cloud of its own, its cloth falling from its own points
    alone = dataclasses.replace(config, lowest_m=None)
    apart = filter_groups(cloud, use, functools.partial(filter, config=alone, params=params),
                          gap_m=groups.GAP_M, estimates=config.memory_estimates)
    if apart is not None:
        return apart
    xyz_m = cloud.xyz_m
    check_memory(cloud.name, config.memory_estimates, xyz_m[use, :2])
    origin, trend_corner = framed(xyz_m[use].min(axis=0), cloud.frame, config)
    # A survey's window: the cloth lies on the survey's particle lattice and falls from the
    # survey's highest inverted point (its lowest z), as in one file of the whole survey.
    anchor = None if cloud.frame is None else Anchor(np.zeros(2, np.float32), np.float32(0.0))
    local, trend = detrended(xyz_m - origin, use, config, trend_corner)
    if trend is not None and (anchor is not None or config.lowest_m is not None):
        # heights less the trend: the survey's lowest z says nothing of them, so the cloth falls
        # from the lowest of them, the survey's where it was fixed (`survey_config`)
        lowest = local[use, 2].min() if config.lowest_m is None else config.lowest_m
        anchor = Anchor(np.zeros(2, np.float32), np.float32(-lowest))
    config = alone                                   # the compiled programs do not read it
    h, w = grid_shape(local, use, cell_m=config.cell_m, anchor=anchor)
    n = len(local)
    capacity = canonical_points(n)
    points = np.zeros((capacity, 3), np.float32)
    points[:n] = local
    valid = np.zeros(capacity, bool)
    valid[:n] = use
    surface = aot.call(point_surface, points, valid, anchor, config=config, shape=canonical_grid((h, w)))
    cloth_u, filled, movable, steps = drop_cloth_in_chunks(surface, params, config=config, progress=progress)
    ground = aot.call(classify, points, valid, surface.corner_m, cloth_u, params, config=config)
    ground = np.asarray(ground)[:n] & use
    diag = TileDiagnostics(*(np.asarray(a)[:h, :w] for a in (cloth_u, filled, movable, surface.exists)), steps)
    xy0 = origin[:2] - BUFFER_PX * config.cell_m
    under = 0.0                                       # the trend under each particle, put back
    if trend is not None:
        rows, cols = np.mgrid[0:h, 0:w]               # row 0 south here, north in the diagnostics
        particles = np.column_stack([cols.ravel(), rows.ravel()]) * config.cell_m + (xy0 - origin[:2])
        under = trend(particles).reshape(h, w)[::-1]
    return Result(ground=ground, diagnostics=Diagnostics(
        cloth_z=origin[2] - np.asarray(diag.cloth_u, np.float64)[::-1] + under,
        surface_z=origin[2] - np.asarray(diag.surface_u, np.float64)[::-1] + under,
        movable=np.asarray(diag.movable)[::-1], steps=int(diag.steps), origin_m=xy0,
        cell_m=config.cell_m))
