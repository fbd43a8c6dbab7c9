"""`gfjax.dmf.filter`: the data-driven morphological filter of Wu et al. (2025), end to end.

```
cloud --(host) W (Eq. 1), voxels, ND_CE (Sec. 2.1-2.2)
      --(JAX while_loop) basal layer ND_BL; (host KD-tree) ND_NG (Sec. 2.3)
      --(JAX, vmap over NGNEM tiles) NGNEM, R_HC, NGNEM_BI, NGNEM_RC, instances (Sec. 2.4-2.5)
      --(host KD-trees + JAX bookkeeping) support nodes, ground points (Sec. 2.6)
```
W is computed once per cloud, so every NGNEM tile of a batch shares one cell size. The jitted
steps run as programs of `gfjax.dmf.programs` (kept across processes by `gfjax.aot`); this
module drives them and the host steps between.
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import math
import time
from collections.abc import Iterable
from typing import NamedTuple

import jax
import numpy as np
from scipy.spatial import cKDTree

from gfjax import adaptive, aot, cache
from gfjax.dmf import extract, neighbours, programs, shapes, stages, voxels
from gfjax.dmf.config import HIDES_LOW_OUTLIERS, MAX_BATCH, Config, Params, adapt
from gfjax.io import columns
from gfjax.io.cloud import CloudView
from gfjax.raster import label_components, relabel_consecutive
from gfjax.result import Result
from gfjax.tiling import groups, windows
from gfjax.tiling.checks import check_memory, checked_options, checked_tiling
from gfjax.tiling.driver import filter_groups
from gfjax.tiling.tiles import Tiling

# The raster stages' outputs pasted from each NGNEM tile's core into the whole raster.
_RASTER_FIELDS = {"ngnem": np.float32, "layer": np.int32, "rhc": bool, "ngnem_bi": bool, "ngnem_rc0": bool,
                  "ngnem_rc": bool}

__all__ = ["Diagnostics", "Prepared", "prepare", "filter", "warm", "run_raster_stages", "MAX_BATCH"]


class Diagnostics(NamedTuple):
    """Intermediate DMF results (host numpy), for notebooks and tests.

    Rasters are `(h, w)` with cell `cell_m`, row 0 = north, covering local x in `[0, w W)`,
    y in `[0, h W)` from `origin_m` (the minimum corner of the used points).

    Attributes:
      cell_m: W [m]; mean_nn_m: the sampled mean 3D nearest-neighbour distance [m].
      origin_m: float64 `(3,)` [m]: add it to local coordinates and elevations.
      nd_ce: near-ground voxel centroids, local float64 `(m, 3)`.
      basal_z: basal-layer elevation of each ND_CE, local float32 `(m,)`.
      in_ndng: ND_CE in ND_NG (3D-nearest ND_CE of some basal node), bool `(m,)`.
      ngnem, ngnem_valid, layer: NGNEM (local elevations, empty cells filled from the
        nearest), its valid cells, voxel layer index.
      rhc, ngnem_bi, ngnem_rc0, ngnem_rc: the masks of Eq. 2, Sec. 2.4, Sec. 2.5 (a), (b).
      instances: object id per cell (1..n, 0 = ground), int32.
      support: `extract.SupportNodes` (local coordinates); m_points: M of Sec. 2.6 (0 if unused).
      basal_iterations: iterations of the basal loop; converged: every bounded loop converged.
      voxels: the voxel columns (`voxels.Voxels`), for re-running step 7.
      table_overflowed: some cylinder held more ND_CE than `Config.basal_table_width`.
      stage_seconds: wall-clock seconds per step ("voxels", "basal", "raster", "extract"),
        JAX compilation included on a first call; they sum to the call's time. Steps 3 and
        4-6 run at the same time (steps 4-6 from a worker thread), so "basal" is step 3 and
        "raster" the wait for steps 4-6 after it.
    """

    cell_m: float
    mean_nn_m: float
    origin_m: np.ndarray
    nd_ce: np.ndarray
    basal_z: np.ndarray
    in_ndng: np.ndarray
    ngnem: np.ndarray
    ngnem_valid: np.ndarray
    layer: np.ndarray
    rhc: np.ndarray
    ngnem_bi: np.ndarray
    ngnem_rc0: np.ndarray
    ngnem_rc: np.ndarray
    instances: np.ndarray
    support: extract.SupportNodes
    m_points: int
    basal_iterations: int
    converged: bool
    voxels: voxels.Voxels
    stage_seconds: dict
    table_overflowed: bool


def _check(cloud, config, params, returns) -> tuple[Config, Params, np.ndarray]:
    return checked_options(cloud, config, params, returns, config_type=Config, params_type=Params,
                           package="gfjax.dmf")


def run_raster_stages(z: np.ndarray, layer: np.ndarray, valid: np.ndarray, cell_m: float, config: Config,
                      *, tiling: Tiling | None = None, progress: bool = False) -> stages.RasterStages:
    """Steps 4-6 on the whole NGNEM: one tile, or a vmapped batch of buffered, padded tiles.

    Args:
      z, layer, valid: ND_CE elevation (float32, local m), layer index (int32), valid (bool),
        each `(h, w)`.
      cell_m: W [m]; config: the stages' static options.
      tiling: the NGNEM's tile cores and buffers (None: `Tiling()`).

    Returns: `RasterStages` of the whole raster (host numpy); a tile's core comes from that
    tile; instance ids are relabelled over the whole raster.
    """
    return _dispatch_raster_stages(z, layer, valid, cell_m, config, tiling or Tiling(), progress=progress)()


def _dispatch_raster_stages(z, layer, valid, cell_m, config, tiling: Tiling, *, progress=False):
    """`run_raster_stages` in two halves: this call starts the work, the returned function
    waits for it and returns the host `RasterStages`. A raster that fits one tile is one
    asynchronous jitted call, so host work between the halves overlaps its execution; a tiled
    raster (host steps between batches) is done at once, its windows driven by the tiling
    layer (`gfjax.tiling.windows`: cores of the tiling at W, full batches, cores pasted)."""
    h, w = z.shape
    core = _tile_core_px(cell_m, tiling)
    buf = math.ceil(tiling.buffer_m / cell_m)
    w_m = np.float32(cell_m)                 # host scalars and arrays go to the jitted calls as
    share = np.float32(config.rc_min_share)  # numpy: no conversion program compiles or runs
    shape = _one_tile_shape((h, w), cell_m, tiling)
    if shape is not None:
        out = programs.raster_tile(*_pad_tile(z, layer, valid, shape), w_m, share, config)
        return lambda: stages.RasterStages(*[np.asarray(a)[:h, :w] if np.ndim(a) == 2 else np.asarray(a) for a in out])
    side = shapes.raster_sides(cell_m, tiling)[-1]          # every window fits the largest: one program per W
    shape = (side, side)

    def tile_of(window: windows.Window):
        (a, b), (c, d) = window.rows, window.cols
        return _pad_tile(z[a:b, c:d], layer[a:b, c:d], valid[a:b, c:d], shape)

    def run_batch(*tiles):                   # every batch filled to MAX_BATCH tiles: one compile
        return programs.raster_batch(*tiles, w_m, share, config)

    fields, outputs = windows.run_windows((h, w), windows.raster_windows((h, w), core_px=core, buffer_px=buf),
                                          tile_of, run_batch, names=_RASTER_FIELDS, max_batch=MAX_BATCH,
                                          progress=progress, desc="dmf raster tiles")
    converged = all(bool(np.all(np.asarray(out.converged)[:n])) for out, n in outputs)
    labels, conv = label_components(jax.device_put(fields["ngnem_rc"]), connectivity=8)
    instances, _ = relabel_consecutive(labels)
    done = stages.RasterStages(**fields, instances=np.asarray(instances), converged=converged and bool(conv))
    return lambda: done


def _tile_core_px(cell_m: float, tiling: Tiling) -> int:
    """Side of a raster tile's core [px]."""
    return max(1, math.ceil(tiling.tile_size_m / cell_m))


def _one_tile_shape(shape: tuple[int, int], cell_m: float, tiling: Tiling) -> tuple[int, int] | None:
    """The padded shape of an NGNEM of `shape` that fits one tile, or None (it is tiled)."""
    h, w = shape
    core = _tile_core_px(cell_m, tiling)
    if h > core or w > core:
        return None
    return shapes.raster_shape((h, w), cell_m, tiling)


def _pad_tile(z, layer, valid, shape):
    h, w = z.shape
    pad = ((0, shape[0] - h), (0, shape[1] - w))
    inside = np.pad(np.ones((h, w), bool), pad)
    return (np.pad(z, pad).astype(np.float32), np.pad(layer, pad).astype(np.int32),
            np.pad(valid, pad).astype(bool), inside)


def _voxels(local: np.ndarray, config: Config, tiling: Tiling, worker) -> tuple[cKDTree | None, float, float, voxels.Voxels]:
    """Steps 1-2 (host): W, voxel columns, ND_CE. Returns `(tree, W, D_m, voxels)`.

    A KD-tree of every point serves W's nearest-neighbour sample and the M-nearest rule
    (Sec. 2.6). It is built on `worker` (scipy builds without the GIL) while the sample is
    drawn here (bcts_2: 0.08 s instead of 0.12 s). Unbalanced, non-compact: 2.5x faster to
    build. Leaves of 64 points when only W needs it (bcts_2: build + sample query 0.073 s vs
    0.087 s with scipy's 16; the M-nearest rule keeps 16, whose order among equidistant points
    it depends on).
    """
    m_rule = config.final_rule in ("m_nearest", "both")
    pending = None
    if m_rule or config.voxel_m is None:
        pending = worker.submit(cKDTree, local, leafsize=16 if m_rule else 64, balanced_tree=False,
                                compact_nodes=False)
    if config.voxel_m is not None:
        tree = pending.result() if pending is not None else None
        cell_m, mean_nn = float(config.voxel_m), float("nan")
    else:
        sample = voxels.nn_sample(len(local), local, fraction=config.sample_fraction, minimum=config.sample_min)
        tree = pending.result()
        cell_m, mean_nn = voxels.voxel_size_m(local, v0=config.v0, fraction=config.sample_fraction,
                                              minimum=config.sample_min, tree=tree, sample=sample)
    # The raster's shape is known from W: its stored program loads while the voxels are binned.
    shape = tuple(int(v) for v in np.floor(columns.highs(local[:, 1::-1]) / cell_m) + 1)
    padded = _one_tile_shape(shape, cell_m, tiling)
    if padded is not None:                          # a tiled raster's programs are not prefetched
        worker.submit(programs.prefetch_raster, padded, config)
    return tree, cell_m, mean_nn, voxels.bin_voxels(local, cell_m)


@cache.persistent
def warm(config: Config | None = None, params: Params | None = None, *, progress: bool = False,
         tiling: Tiling | None = None) -> int:
    """Load, or compile and store (`gfjax.aot`), the programs `filter` runs on a cloud of any
    size at W of `shapes.WARM_VOXELS_M` (1 and 2 m) whose NGNEM is near square or tiled: the
    raster stages on every shape of one tile near square (`shapes.warm_shapes`) and on a batch
    of the largest side, the basal loop on every node capacity up to
    `shapes.NODE_WARM_MAX_CAPACITY`, and the height rule on every such shape with every
    canonical point capacity. Nothing runs; nothing is kept when the program cache is off.
    Returns the number of programs prepared (`gfjax warmup`)."""
    from gfjax.tiling.buckets import canonical_capacities

    config, tiling = config or Config(), tiling or Tiling()
    one_tile, batched = set(), set()
    for cell_m in shapes.WARM_VOXELS_M:
        core = _tile_core_px(cell_m, tiling)
        sides = shapes.raster_sides(cell_m, tiling)
        largest = shapes.raster_shape((core, core), cell_m, tiling)[0]
        one_tile.update(shapes.warm_shapes(tuple(s for s in sides if s <= largest)))
        batched.add(sides[-1])

    jobs = [functools.partial(programs.prefetch_raster, shape, config) for shape in sorted(one_tile)]
    jobs += [functools.partial(programs.prefetch_raster, (s, s), config, batch=MAX_BATCH) for s in sorted(batched)]
    cap = shapes.NODE_MIN_CAPACITY
    while cap <= shapes.NODE_WARM_MAX_CAPACITY:
        jobs.append(functools.partial(programs.prefetch_basal, cap, config))
        cap *= 2
    if config.final_rule in ("height", "both"):
        for shape in sorted(one_tile):
            for n in canonical_capacities():
                jobs.append(functools.partial(programs.prefetch_height_rule, n, shape))
    return aot.warm_all(jobs, progress=progress, desc="dmf programs")


def _padded_nodes(centroid: np.ndarray, table: neighbours.NeighbourTable, width: int):
    """The basal loop's inputs padded to a canonical shape: `shapes.node_capacity` rows, `width`
    (`Config.basal_table_width`) columns. A padded node, or slot, holds its own row and is
    invalid: it never enters another node's median and never moves, so the basal layer of the
    real nodes is the unpadded one."""
    m, k = table.index.shape
    cap = shapes.node_capacity(m)
    xyz = np.zeros((cap, 3), np.float32)
    xyz[:m] = centroid
    index = np.repeat(np.arange(cap, dtype=np.int32)[:, None], width, axis=1)
    index[:m, :k] = table.index
    valid = np.zeros((cap, width), bool)
    valid[:m, :k] = table.valid
    return xyz, index, valid


def _layers(vox: voxels.Voxels, cell_m: float, config: Config, tiling: Tiling, worker, lap, progress: bool):
    """Steps 3 and 4-6, which are independent. The raster stages (steps 4-6) are dispatched on
    `worker`, so loading their program (a new process) and running them overlap the host work
    of step 3 here: the cylinder table, the basal loop (asynchronous JAX), then ND_NG (host
    KD-tree). Returns `(in_ndng, basal layer (host z), raster stages, NGNEM valid mask,
    cylinder table overflowed)`."""
    h, w = vox.shape
    z_r = np.zeros(h * w, np.float32)
    k_r = np.zeros(h * w, np.int32)
    v_r = np.zeros(h * w, bool)
    z_r[vox.cell], k_r[vox.cell], v_r[vox.cell] = vox.centroid[:, 2], vox.layer, True
    # The programs still to come load on `worker` in the order they run. One tile's raster
    # stages only start there (asynchronous JAX), so the basal loop's program loads next, while
    # the cylinder table is built here, then step 7's. A tiled raster holds `worker` until it is
    # done: step 7's program loads before it, and the basal loop's here.
    step7 = ([functools.partial(programs.prefetch_height_rule, len(vox.point_cell),
                                shapes.raster_shape((h, w), cell_m, tiling))]
             if config.final_rule in ("height", "both") else [])
    if _one_tile_shape((h, w), cell_m, tiling) is None:
        before, after = step7, []
    else:
        before, after = [], [functools.partial(programs.prefetch_basal, shapes.node_capacity(len(vox.centroid)),
                                               config), *step7]
    for job in before:
        worker.submit(job)
    raster_future = worker.submit(_dispatch_raster_stages, z_r.reshape(h, w), k_r.reshape(h, w), v_r.reshape(h, w),
                                  cell_m, config, tiling, progress=progress)
    for job in after:
        worker.submit(job)
    table = neighbours.cylinder_table(vox.centroid[:, :2], radius_m=config.basal_radius_w * cell_m,
                                      k=config.basal_neighbours, max_width=config.basal_table_width)
    cap = np.inf if config.basal_sink_cap_w is None else config.basal_sink_cap_w * cell_m
    m = len(vox.centroid)
    basal = programs.basal_layer(*_padded_nodes(vox.centroid, table, config.basal_table_width), np.float32(cap),
                                 config)
    node_tree = cKDTree(vox.centroid)                       # while the basal loop runs
    basal_z = np.asarray(basal.z)[:m]
    basal_xyz = np.concatenate([vox.centroid[:, :2], basal_z[:, None].astype(np.float64)], axis=1)
    in_ndng = np.zeros(len(vox.cell), bool)
    in_ndng[neighbours.nearest_node(vox.centroid, basal_xyz, tree=node_tree)] = True
    lap("basal")
    rs = raster_future.result()()
    lap("raster")
    basal = basal._replace(z=basal_z, nearest=np.asarray(basal.nearest)[:m])
    return in_ndng, basal, rs, v_r.reshape(h, w), table.overflowed


def survey_config(config: Config, clouds: Iterable[np.ndarray], frame=None) -> Config:
    """`config` with W fixed once for a whole survey, so every file and its halo share one voxel
    lattice (a file's own estimate could round to another whole metre than its neighbour's).

    Eq. 1 over the survey: the mean nearest-neighbour distance of every file's sample
    (`voxels.nn_sample`, neighbours found within the file). A `config` with `voxel_m` set is
    returned as it is.

    Args:
      config: the survey's settings.
      clouds: each file's points filtered, float64 `(n_i, 3)` [m], and bool `(n_i,)`
        marking the file's own (`Method.survey_config`).
      frame: the survey's frame (W does not depend on it).
    """
    if config.voxel_m is not None:
        return config
    total, count = 0.0, 0
    for xyz, own in clouds:
        xyz = xyz[own]
        if len(xyz) >= 2:
            dist = voxels.nn_distances(np.asarray(xyz, np.float64), fraction=config.sample_fraction,
                                       minimum=config.sample_min)
            total, count = total + float(dist.sum()), count + len(dist)
    return dataclasses.replace(config, voxel_m=voxels.size_of(total / count, config.v0) if count else 1.0)


class Prepared(NamedTuple):
    """Steps 1-6 of DMF on one cloud: everything before the support nodes and the final rule
    (Sec. 2.6). Only step 7 reads `v1`, `fill_neighbours`, `support_z`, `support_elevation`,
    `support_position` and `Params` (and `final_rule`, whose M-nearest search also needs `tree`), so one preparation
    serves every value of those (`gfjax.dmf.tuning` tries them on it).

    Attributes:
      config: the settings the steps ran with (`voxel_m` set on a survey's window).
      tiling: the NGNEM's tiles.
      use: bool `(n,)` the cloud's points filtered; the arrays below hold those only.
      local: float64 `(u, 3)` used points less `origin` [m]; origin: float64 `(3,)` [m].
      tree: a `cKDTree` of `local` (None when neither W nor the M-nearest rule needed one).
      cell_m, mean_nn: W and the sampled mean nearest-neighbour distance [m].
      vox: the voxel columns; in_ndng, basal: step 3; rs: steps 4-6 (`stages.RasterStages`);
      ngnem_valid: the NGNEM's valid cells; overflowed: a basal table overflowed.
      seconds: wall-clock seconds per step so far.
    """

    config: Config
    tiling: Tiling
    use: np.ndarray
    local: np.ndarray
    origin: np.ndarray
    tree: cKDTree | None
    cell_m: float
    mean_nn: float
    vox: voxels.Voxels
    in_ndng: np.ndarray
    basal: object
    rs: stages.RasterStages
    ngnem_valid: np.ndarray
    overflowed: bool
    seconds: dict

    @property
    def object_cell(self) -> np.ndarray:
        """bool `(h * w,)`: NGNEM_RC, the cells of object regions."""
        return np.asarray(self.rs.ngnem_rc).reshape(-1)


def prepare(cloud: CloudView, use: np.ndarray, config: Config, *, tiling: Tiling | None = None,
            progress: bool = False) -> Prepared:
    """Steps 1-6 on the points `use` (bool `(n,)`, at least one) of `cloud` (`config` checked;
    `tiling`: the NGNEM's tiles, None: `Tiling()`)."""
    tiling = tiling or Tiling()
    xyz = cloud.xyz_m
    xyz = xyz if use.all() else xyz[use]          # no 20 MB copy when every point is used
    check_memory(cloud.name, functools.partial(config.memory_estimates, tiling=tiling), xyz[:, :2])
    clock = [time.perf_counter()]
    seconds: dict[str, float] = {}

    def lap(name):                           # steps 3 and 4-6 interleave: their laps add up
        now = time.perf_counter()
        seconds[name] = seconds.get(name, 0.0) + now - clock[0]
        clock[0] = now

    origin = columns.lows(xyz)              # = xyz.min(axis=0), 30x faster
    window_nn = float("nan")
    if cloud.frame is not None:
        # A survey's window: its voxels (and so its NGNEM cells and layers) lie on the lattice
        # the whole survey in one file would have. W sets the lattice, so it is known first:
        # the survey's (`survey_config`), else estimated on the window.
        if config.voxel_m is None:
            cell_m, window_nn = voxels.voxel_size_m(xyz - origin, v0=config.v0, fraction=config.sample_fraction,
                                                    minimum=config.sample_min)
            config = dataclasses.replace(config, voxel_m=cell_m)
        origin = cloud.frame.snap(origin, config.voxel_m)
    local = xyz - origin
    with concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="gfjax-dmf") as worker:
        tree, cell_m, mean_nn, vox = _voxels(local, config, tiling, worker)
        mean_nn = window_nn if np.isnan(mean_nn) else mean_nn
        lap("voxels")
        in_ndng, basal, rs, ngnem_valid, overflowed = _layers(vox, cell_m, config, tiling, worker, lap, progress)
    return Prepared(config, tiling, use, local, origin, tree, cell_m, mean_nn, vox, in_ndng, basal, rs, ngnem_valid,
                    overflowed, seconds)


@cache.persistent
@adaptive.follows(adapt, Config, Params, hides_low_outliers=HIDES_LOW_OUTLIERS)
def filter(cloud: CloudView, *, config: Config | None = None, params: Params | None = None,  # noqa: A001
           returns: str = "all", progress: bool = False, tiling: Tiling | None = None) -> Result:
    """Classify ground points with DMF (Wu et al. 2025; our readings: SPEC section 3).

    Args:
      cloud: the point cloud (metres via `cloud.xyz_m`; noise and withheld points ignored).
      config: static options (`Config`); params: traced thresholds (`Params`).
      returns: "all" or "last" returns.
      progress: show a progress bar over NGNEM tile batches.
      tiling: the tile cores and buffers the NGNEM raster is cut into for the batched raster
        stages (default `Tiling()`: 500 m, 50 m; `gfjax.tiling.tiles.Tiling`).

    Returns:
      `Result(ground, diagnostics, instance_id)`: ground bool `(n,)`; `Diagnostics` (None
      when groups of points far apart were filtered one by one: `gfjax.tiling.driver.filter_groups`);
      instance_id uint32 `(n,)`: the object region (NGNEM_RC instance) of each non-ground
      point's cell, 0 for ground points and points outside every object region.
    """
    config, params, use = _check(cloud, config, params, returns)
    tiling = checked_tiling(tiling)
    n_all = cloud.n_points
    ground_all = np.zeros(n_all, bool)
    instance_all = np.zeros(n_all, np.uint32)
    if not use.any():
        return Result(ground=ground_all, diagnostics=None, instance_id=instance_all)
    apart = filter_groups(cloud, use, functools.partial(filter, config=config, params=params, tiling=tiling),
                          gap_m=max(groups.GAP_M, tiling.buffer_m),
                          estimates=functools.partial(config.memory_estimates, tiling=tiling))
    if apart is not None:
        return apart
    prep = prepare(cloud, use, config, tiling=tiling, progress=progress)
    clock = time.perf_counter()
    # Step 7: support nodes and the final rule.
    nodes, ground, m_points = extract.extract_ground(prep.local, prep.vox, prep.object_cell, prep.in_ndng,
                                                     prep.config, params, points_tree=prep.tree, tiling=prep.tiling)
    instance = np.asarray(prep.rs.instances).reshape(-1)[prep.vox.point_cell].astype(np.uint32)
    instance[ground] = 0
    seconds = {**prep.seconds, "extract": time.perf_counter() - clock}
    ground_all[use] = ground
    instance_all[use] = instance
    rs, basal = prep.rs, prep.basal
    diagnostics = Diagnostics(
        cell_m=prep.cell_m, mean_nn_m=prep.mean_nn, origin_m=prep.origin, nd_ce=prep.vox.centroid, basal_z=basal.z,
        in_ndng=prep.in_ndng, ngnem=np.asarray(rs.ngnem), ngnem_valid=prep.ngnem_valid, layer=np.asarray(rs.layer),
        rhc=np.asarray(rs.rhc), ngnem_bi=np.asarray(rs.ngnem_bi), ngnem_rc0=np.asarray(rs.ngnem_rc0),
        ngnem_rc=np.asarray(rs.ngnem_rc), instances=np.asarray(rs.instances), support=nodes, m_points=int(m_points),
        basal_iterations=int(basal.iterations), converged=bool(basal.converged) and bool(rs.converged),
        table_overflowed=prep.overflowed,
        voxels=prep.vox, stage_seconds=seconds)
    return Result(ground=ground_all, diagnostics=diagnostics, instance_id=instance_all)
