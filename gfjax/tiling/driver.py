"""Run a per-tile-batch classifier over a cloud's buffered tiles; filter groups far apart alone.

The driver of the raster filters that work tile by tile (`gfjax.smrf`, `gfjax.pmf`, and
SparseGF's SMRF prior): cut the cloud into buffered tiles (`tiles.split`), pad them into
batches of one raster shape (`batches.batches`, sizes from `buckets`), run each batch through
one jitted, vmapped `classify_batch` (one compile per batch shape), keep the core points'
labels (`tiles.merge`), and paste each tile's core out of its per-tile rasters into
whole-cloud rasters (`mosaic`; the padded tile layout is `gfjax.raster.domain_mask`). A cloud
of groups of points far apart (`groups.members`) is classified group by group
(`classify_groups`), and the whole-cloud methods (CSF, DMF, MASF) filter such a cloud group
by group through `filter_groups`.

Host-side numpy around the jitted batch function.
"""
from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
from jaxtyping import Array, Bool, Float

from gfjax.io.cloud import CloudView, Points
from gfjax.result import Result
from gfjax.tiling import batches as batches_lib
from gfjax.tiling import buckets, groups
from gfjax.tiling import tiles as tiles_lib
from gfjax.tiling.checks import Estimates, check_memory, checked_options, lattice_of
from gfjax.tiling.mosaic import Mosaic, mosaic

__all__ = ["GROUP_GAP_M", "ClassifyBatch", "filter_groups", "run_batches", "warm", "tiled_groups", "classify_cloud",
           "classify_groups", "TiledRun", "Filtered", "filter_cloud"]

# A cloud whose groups of points at least this far apart (or a tiling's buffer, if larger) fill a
# quarter of its box or less is filtered group by group, each group as a cloud of its own
# (`classify_groups`): a tile's context reaches its buffer (50 m by default), so no group's
# points are another's context, and the empty box between groups costs nothing [m].
GROUP_GAP_M = 50.0

ClassifyBatch = Callable[..., tuple[Bool[Array | np.ndarray, "b n"], tuple]]
"""`classify_batch(xyz (b, n, 3) float32, valid (b, n) bool, hw (b, 2) int32, params, *, config,
shape=(h, w)) -> (ground (b, n) bool, diagnostics)`, every diagnostics field a `(b, h, w)`
raster whose tile data sit in the south-west corner (`gfjax.raster.domain_mask`)."""


def filter_groups(cloud: CloudView, use: np.ndarray, filter_one: Callable[[CloudView], Result], *,
                  gap_m: float, estimates: Estimates | None) -> Result | None:
    """A whole-cloud method's `filter` on a cloud of groups of points far apart: each group as
    a cloud of its own, or None for a cloud to filter whole.

    CSF, DMF and MASF build rasters over a cloud's box. When the used points' groups at least
    `gap_m` apart (`groups.members`: no method's window reaches from one to the next) fill a
    quarter of the box or less (a stray point kilometres away, flight lines far apart, points
    spread thinly over a large area), each group is filtered alone by `filter_one`, so the empty
    box costs nothing and each group gets exactly the labels it gets alone; a group of one
    point is ground without a run (SPEC section 1: a single point is ground, as each method's
    own run on it gives). A survey's window (`cloud.frame` set) is filtered whole: it keeps the
    survey's lattice.

    Args:
      cloud: the cloud; use: bool `(n,)` its points to filter (`checks.checked_options`).
      filter_one: the method's `filter` on a cloud whose points are all used.
      gap_m: the emptiness that separates groups (`groups.GAP_M` or the method's reach) [m].
      estimates: the method's memory estimates, checked on the largest group's box first.

    Returns:
      `Result(ground, None, instance_id)` (instance ids, when the method gives them, are
      numbered on across groups), or None: the cloud is one group, or its groups fill its box.
    """
    if cloud.frame is not None:
        return None
    xyz_m = cloud.xyz_m
    used = np.flatnonzero(use)
    members = groups.members(xyz_m[:, :2] if len(used) == len(use) else xyz_m[used, :2], gap_m, index=used)
    if members is None:
        return None
    widest = max(members, key=lambda m: float(np.prod(np.ptp(xyz_m[m, :2], axis=0) + 1.0)))
    check_memory(cloud.name, estimates, xyz_m[widest, :2])
    ground = np.zeros(len(use), bool)
    instance_id, last_id = None, 0
    for index in members:
        if len(index) == 1:
            ground[index] = True
            continue
        result = filter_one(Points.of_xyz(xyz_m[index], name=cloud.name))
        ground[index] = result.ground
        if result.instance_id is not None:
            instance_id = np.zeros(len(use), np.uint32) if instance_id is None else instance_id
            ids = result.instance_id.astype(np.uint32)
            instance_id[index] = np.where(ids > 0, ids + np.uint32(last_id), 0)
            last_id += int(ids.max(initial=0))
    return Result(ground=ground, diagnostics=None, instance_id=instance_id)


def run_batches(tiles: Sequence[tiles_lib.Tile], classify_batch: ClassifyBatch, params: Any, config: Any, *,
                lattice: tiles_lib.Lattice, max_batch: int, progress: bool = False, desc: str = "tiles",
                keep_diagnostics: bool = True, small: bool = False) -> tuple[list[np.ndarray], list[tuple | None]]:
    """Classify tiles batch by batch (`batches.batches`, one `classify_batch` call per batch).

    Args:
      tiles: from `tiles.split`.
      classify_batch: the method's vmapped batch function (`ClassifyBatch`).
      params, config: passed through (`config` static).
      lattice: the tiling the tiles were cut with (it sets the canonical raster sides).
      max_batch: most tiles per call.
      progress: show a progress bar over batches, labelled `desc`.
      keep_diagnostics: crop and keep the per-tile rasters (else None per tile).
      small: windows of at most `buckets.SMALL_SIDES_PX[-1]` cells a side run in
        `batches.small_batches` when there are more than `max_batch` of them (a cloud of small
        groups far apart, `classify_groups`).

    Returns:
      `(labels, diagnostics)` in the order of `tiles`: per tile a bool `(tile.n_points,)`
      ground array, and the batch's diagnostics NamedTuple (host numpy) cropped to the tile's
      own extent, each field `tile.shape` (or None when not kept).
    """
    position = {id(tile): i for i, tile in enumerate(tiles)}
    labels: list[np.ndarray | None] = [None] * len(tiles)
    diagnostics: list[tuple | None] = [None] * len(tiles)
    sides = buckets.canonical_sides(*lattice)
    fits = [small and max(tile.shape) <= buckets.SMALL_SIDES_PX[-1] for tile in tiles]
    if sum(fits) <= max_batch:
        # a few run as canonical windows, padded to the side of the others' smallest if there are
        # others: no program beyond those the others (or `gfjax warmup`) compiled
        fits = [False] * len(tiles)
        if small:
            floor = min((max(t.shape) for t in tiles if max(t.shape) > buckets.SMALL_SIDES_PX[-1]), default=0)
            sides = tuple(s for s in sides if s >= floor) or sides[-1:]
    padded = [*batches_lib.small_batches([t for t, f in zip(tiles, fits) if f], max_batch=max_batch),
              *batches_lib.batches([t for t, f in zip(tiles, fits) if not f], max_batch=max_batch, sides=sides)]
    if progress:
        from tqdm.auto import tqdm
        padded = tqdm(padded, desc=desc, unit="batch")
    for batch in padded:
        ground, diag = classify_batch(batch.xyz, batch.valid, batch.hw, params, config=config,
                                      shape=batch.shape)
        ground = np.asarray(ground)
        diag = type(diag)(*(np.asarray(a) for a in diag)) if keep_diagnostics else None
        for b, tile in enumerate(batch.tiles):
            i = position[id(tile)]
            labels[i] = ground[b, :tile.n_points]
            if diag is not None:
                h, w = tile.shape
                rows = slice(batch.shape[0] - h, batch.shape[0])
                diagnostics[i] = type(diag)(*(a[b, rows, :w] for a in diag))
    return labels, diagnostics


def warm(classify_batch: ClassifyBatch, params: Any, config: Any, *, tiling: tiles_lib.Tiling | None = None,
         progress: bool = False, desc: str = "programs") -> int:
    """Load, or compile and store (`gfjax.aot`), every program `run_batches` runs for a
    one-tile batch of `tiling` (None: `Tiling()`) at `config.cell_m`: each canonical raster side
    (`buckets.canonical_sides`) with each point capacity a tile runs at (`buckets.tile_capacities`).
    Nothing runs; batches of
    `max_batch` tiles (surveys of many tiles) still compile on first use. Nothing is kept
    when the program cache is off. Returns the number of shape pairs prepared."""
    import jax

    from gfjax import aot

    spec = jax.ShapeDtypeStruct

    def job(side, cap):
        return lambda: classify_batch(spec((1, cap, 3), np.float32), spec((1, cap), np.bool_), spec((1, 2), np.int32),
                                      params, config=config, shape=(side, side))

    return aot.warm_all([job(side, cap) for side in buckets.canonical_sides(*lattice_of(tiling, config.cell_m))
                         for cap in buckets.tile_capacities()], progress=progress, desc=desc)


class TiledRun(NamedTuple):
    """What `classify_cloud` returns.

    Attributes:
      ground: bool `(n,)` labels of the whole cloud (False for points outside `use`).
      tiles: the tiles of `tiles.split` (empty when no point is used).
      diagnostics: per tile, the cropped diagnostics of `run_batches`.
    """

    ground: np.ndarray
    tiles: list[tiles_lib.Tile]
    diagnostics: list[tuple | None]


def classify_cloud(xyz_m: Float[np.ndarray, "n 3"], use: Bool[np.ndarray, " n"], classify_batch: ClassifyBatch,
                   params: Any, config: Any, *, lattice: tiles_lib.Lattice, max_batch: int, progress: bool = False,
                   desc: str = "tiles", frame: tiles_lib.Frame | None = None) -> TiledRun:
    """Split a cloud into buffered tiles, run `classify_batch` over them, merge the core labels.

    Args:
      xyz_m: float64 `(n, 3)` coordinates [m].
      use: bool `(n,)` points to classify.
      classify_batch, params, max_batch, progress, desc: as `run_batches`.
      config: the method's static config.
      lattice: the tiling at the method's cell (`lattice_of`).
      frame: the tiling's box (`tiles.split`; default the used points' own).

    Returns:
      `TiledRun(ground, tiles, diagnostics)`.
    """
    tiles = tiles_lib.split(xyz_m, **lattice._asdict(), use=use, frame=frame)
    if not tiles:
        return TiledRun(ground=np.zeros(len(use), bool), tiles=[], diagnostics=[])
    labels, diagnostics = run_batches(tiles, classify_batch, params, config, lattice=lattice, max_batch=max_batch,
                                      progress=progress, desc=desc)
    ground = tiles_lib.merge(len(use), tiles, labels) & use
    return TiledRun(ground=ground, tiles=tiles, diagnostics=diagnostics)


def classify_groups(xyz_m: Float[np.ndarray, "n 3"], use: Bool[np.ndarray, " n"], members: Sequence[np.ndarray],
                    classify_batch: ClassifyBatch, params: Any, config: Any, *, lattice: tiles_lib.Lattice,
                    max_batch: int, progress: bool = False, desc: str = "tiles",
                    keep_diagnostics: bool = False) -> TiledRun:
    """`classify_cloud` on each group of points far apart (`groups.members`) as a cloud of its
    own: its lattice starts at its own corner and its windows end at its own box, so a group
    is labelled as it would be alone, and the empty box between groups costs nothing (a cloud
    spread over kilometres runs about its points' tiles, most of them a few cells wide:
    `run_batches(small=True)`). All groups' tiles share the batches.

    Args:
      xyz_m, use, classify_batch, params, config, lattice, max_batch, progress, desc: as
        `classify_cloud` (`frame` is each group's own); keep_diagnostics: as `run_batches`.
      members: the groups, each an int array of indices into `xyz_m` (`groups.members`).

    Returns:
      `TiledRun(ground, tiles, diagnostics)`: tiles index the whole cloud.
    """
    tiles = []
    for index in members:
        tiles += [dataclasses.replace(tile, index=index[tile.index])
                  for tile in tiles_lib.split(xyz_m[index], **lattice._asdict())]
    labels, diagnostics = run_batches(tiles, classify_batch, params, config, lattice=lattice, max_batch=max_batch,
                                      progress=progress, desc=desc, keep_diagnostics=keep_diagnostics, small=True)
    return TiledRun(ground=tiles_lib.merge(len(use), tiles, labels) & use, tiles=tiles, diagnostics=diagnostics)


class Filtered(NamedTuple):
    """What `filter_cloud` gives a tiled method's `filter`.

    Attributes:
      ground: bool `(n,)`, False for points not used.
      config: the config the cloud was filtered with (defaults filled in).
      cores: the tiles' diagnostics pasted into whole-cloud rasters (`mosaic`), or None when no
        tile ran or the cloud was filtered group by group (its box is mostly empty).
      n_tiles: tiles run.
    """

    ground: np.ndarray
    config: Any
    cores: Mosaic | None
    n_tiles: int


def tiled_groups(xy_m: np.ndarray, use: np.ndarray, lattice: tiles_lib.Lattice,
                 frame: tiles_lib.Frame | None) -> list[np.ndarray] | None:
    """The groups of points far apart that a tiled method classifies each on tiles of its own
    (`classify_groups`): `groups.members` of the used points' x, y `xy_m` `(k, 2)` [m] at
    `GROUP_GAP_M` or the `lattice`'s buffer if larger, as indices into `use` (bool `(n,)`); None
    for one lattice over the cloud (`classify_cloud`), always on a survey's window (`frame`),
    which keeps the survey's lattice."""
    if frame is not None:
        return None
    return groups.members(xy_m, max(GROUP_GAP_M, lattice.buffer_m), index=np.flatnonzero(use))


def filter_cloud(cloud: Any, config: Any, params: Any, returns: str, *, tiling: tiles_lib.Tiling | None,
                 config_type: type, params_type: type, package: str, classify_batch: ClassifyBatch, max_batch: int,
                 rasters: Sequence[str], heights: Sequence[str], progress: bool = False) -> Filtered:
    """A tiled method's `filter` up to its diagnostics: options checked (`checked_options`,
    `lattice_of`: `tiling` None is `Tiling()`), tiles classified (`classify_cloud`) and their
    diagnostics `rasters` mosaicked (`heights`: those shifted to the cloud's vertical frame);
    a cloud of groups far apart (`groups.members`; not a survey's window) is classified
    group by group instead (`classify_groups`), without a mosaic."""
    config, params, use = checked_options(cloud, config, params, returns, config_type=config_type,
                                          params_type=params_type, package=package)
    lattice = lattice_of(tiling, config.cell_m, name=cloud.name)
    estimates = functools.partial(config.memory_estimates, tiling=tiling)
    desc = f"{package.rsplit('.', 1)[-1]} tiles"
    xy_m = cloud.xyz_m[:, :2] if use.all() else cloud.xyz_m[use, :2]     # no copy when every point is used
    apart = tiled_groups(xy_m, use, lattice, cloud.frame)
    if apart is not None:
        check_memory(cloud.name, estimates, None)
        run = classify_groups(cloud.xyz_m, use, apart, classify_batch, params, config, lattice=lattice,
                              max_batch=max_batch, progress=progress, desc=desc)
        return Filtered(ground=run.ground, config=config, cores=None, n_tiles=len(run.tiles))
    check_memory(cloud.name, estimates, xy_m)
    run = classify_cloud(cloud.xyz_m, use, classify_batch, params, config, lattice=lattice, max_batch=max_batch,
                         frame=cloud.frame, progress=progress, desc=desc)
    cores = None
    if run.tiles:
        cores = mosaic(run.tiles, run.diagnostics, names=rasters, heights=heights, cell_m=config.cell_m)
    return Filtered(ground=run.ground, config=config, cores=cores, n_tiles=len(run.tiles))
