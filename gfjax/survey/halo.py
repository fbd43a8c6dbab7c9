"""A file of a survey with its halo: the neighbours' points its tiles' windows can reach; or the
whole survey as one cloud.

A tiled method (SMRF, PMF: `gfjax.methods.lattice` gives its tiling at its cell) lays its tiles on
the survey's frame, so the windows of the tiles holding a file's points are known before
filtering: the file's halo is every point of the other files inside them (plus a cell), and
those windows then hold exactly the points they would hold in one file of the whole survey:
the file's labels are the same. A method that does not tile gets the points within
`HALO_M` of the file's bounding box as context (or its own width: `Method.survey_halo`,
`halo_width`), which removes most, not all, of the seam. A
method whose labels depend on the whole cloud (`Method.whole_cloud`: CSF) filters the whole survey as
one cloud when it fits the memory budget (`fits_whole`, `survey_labels`), so its labels are
exactly one file's.
"""
from __future__ import annotations

import dataclasses
import math
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from gfjax import adaptive, heap, limits
from gfjax.io import point_store
from gfjax.io.cloud import Cloud, Frame, Points, use_mask
from gfjax.method import Method
from gfjax.result import Result
from gfjax.survey.catalog import STORE, Catalog, Entry
from gfjax.tiling.tiles import Lattice

HALO_M = 50.0           # context around a file for methods that do not tile [m]
SPILL_BYTES_PER_POINT = 40   # `survey_terrain`'s columns of a point on disk, at most: x, y, z and a last return's x, y


def halo_width(method: Method, config) -> float:
    """The context [m] a survey gives each file of `method` run with `config` (the survey's,
    `survey_config`) when it labels neither tile by tile nor as one cloud: its own
    (`Method.survey_halo`) or `HALO_M`; for a method whose labels depend on the whole cloud,
    `HALO_M` or its own where that is wider."""
    if method.survey_halo is None:
        return HALO_M
    own = float(method.survey_halo(config))
    return max(HALO_M, own) if method.whole_cloud else own


def halo_region(box: Frame, frame: Frame, lattice: Lattice | None,
                halo_m: float = HALO_M) -> tuple[np.ndarray, np.ndarray]:
    """The x-y box `(lo (2,), hi (2,))` [m] whose points can share a window with a point of `box`.

    A tiled method (`lattice`, its tiling at its cell): the windows of the tiles whose cores
    meet `box`, laid on `frame` as `gfjax.tiling.tiles.split` lays them, grown by one cell; other
    methods (None): `box` grown by `halo_m` (`halo_width`).
    """
    lo, hi = np.asarray(box.origin_m[:2], np.float64), np.asarray(box.upper_m, np.float64)
    if lattice is None:
        return lo - halo_m, hi + halo_m
    origin = np.asarray(frame.origin_m[:2], np.float64)
    return tiles_region(np.floor((lo - origin) / lattice.tile_size_m), np.floor((hi - origin) / lattice.tile_size_m),
                        frame, lattice)


def tiles_region(first: np.ndarray, last: np.ndarray, frame: Frame, lattice: Lattice) -> tuple[np.ndarray, np.ndarray]:
    """The x-y box `(lo (2,), hi (2,))` [m] of the windows of the tiles with keys from `first`
    to `last` `(col, row)` of `frame`'s lattice, grown by one cell."""
    tile, cell = lattice.tile_size_m, lattice.cell_m
    origin = np.asarray(frame.origin_m[:2], np.float64)
    core_px = tile / cell
    buffer_px = math.ceil(lattice.buffer_m / cell - 1e-9)
    lo_px = np.floor(np.asarray(first) * core_px) - buffer_px - 1
    hi_px = np.ceil((np.asarray(last) + 1) * core_px) + buffer_px + 1
    return origin + lo_px * cell, origin + hi_px * cell


def overlaps(frame: Frame | None, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether a file's `frame` meets the x-y box from `lo` to `hi` [m]."""
    return frame is not None and not (np.any(frame.origin_m[:2] > hi) or np.any(frame.upper_m < lo))


def within_box(catalog: Catalog, lo: np.ndarray, hi: np.ndarray, *,
               skip: int | None = None) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """`(j, index, records)` of each file `j` of the catalog (but `skip`) with points inside the
    x-y box `lo`..`hi` [m] (`Entry.within`); a file whose frame misses the box is not read."""
    for j, entry in enumerate(catalog.entries):
        if j != skip and overlaps(entry.frame, lo, hi):
            index, records = entry.within(lo, hi)
            if index.size:
                yield j, index, records


def ground_near(catalog: Catalog, i: int, lo: np.ndarray, hi: np.ndarray,
                ground_of: Callable[[int], np.ndarray]) -> np.ndarray:
    """The other files' ground points inside the x-y box `lo`..`hi`, float64 `(k, 3)` [m];
    `ground_of(j)`: file `j`'s labels, bool `(n_j,)`."""
    parts = [np.empty((0, 3), np.float64)]
    for j, index, records in within_box(catalog, lo, hi, skip=i):
        parts.append(np.asarray(records["xyz_m"])[ground_of(j)[index]])
    return np.concatenate(parts)


def classified_ground_near(catalog: Catalog, i: int, xyz_m: np.ndarray, buffer_m: float,
                           ground_class: int) -> np.ndarray:
    """The other files' points of class `ground_class` (but the ignored ones) within `buffer_m`
    of the x-y box of file `i`'s points `xyz_m` `(n, 3)` [m]: float64 `(k, 3)` [m]. The ground a
    file's TIN (heights above ground, a DTM, a CHM) needs at its borders."""
    lo, hi = xyz_m[:, :2].min(axis=0) - buffer_m, xyz_m[:, :2].max(axis=0) + buffer_m
    parts = [np.empty((0, 3), np.float64)]
    for _, _, records in within_box(catalog, lo, hi, skip=i):
        ground = (np.asarray(records["classification"]) == ground_class) & ~np.asarray(records["ignored"])
        parts.append(np.asarray(records["xyz_m"])[ground])
    return np.concatenate(parts)


def window(catalog: Catalog, i: int, cloud: Cloud | Points, lattice: Lattice | None, halo_m: float = HALO_M) -> Points:
    """File `i` of the catalog (read as `cloud`) followed by its halo (`halo_region`), on the
    survey's frame."""
    entry = catalog.entries[i]
    parts = [dict(xyz_m=cloud.xyz_m, classification=cloud.classification, return_number=cloud.return_number,
                  number_of_returns=cloud.number_of_returns, ignored=cloud.ignored)]
    if entry.frame is not None:
        lo, hi = halo_region(entry.frame, catalog.frame, lattice, halo_m)
        for _, _, chosen in within_box(catalog, lo, hi, skip=i):
            parts.append({name: np.asarray(chosen[name]) for name in parts[0]})
    fields = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
    return Points(**fields, name=cloud.name, frame=catalog.frame)


def _file_points(catalog: Catalog, returns: str, terrain: adaptive.Terrain | None,
                 halo_m: float) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Per file of the catalog, its used points (`use_mask` of `returns`) and, with `halo_m` >
    0, those of its halo (`window`), float64 `(k, 3)` [m], and bool `(k,)` marking the file's
    own; with a `terrain`, the low outliers (`adaptive.hide`, on the survey's frame) left out,
    as a run whose values follow the data leaves them."""
    for i, entry in enumerate(catalog.entries):
        own = Points.from_records(entry.records(), str(entry.path), catalog.frame)
        points = window(catalog, i, own, None, halo_m) if halo_m > 0 else own
        used = points.filter_mask(returns)
        low = None if terrain is None else adaptive.hide(points, terrain, returns=returns)
        if low is not None:
            used &= ~low
        yield points.xyz_m[used], (np.arange(points.n_points) < own.n_points)[used]


def survey_config(method: Method, config, catalog: Catalog, *, returns: str = "all",
                  hidden_by: adaptive.Terrain | None = None):
    """`config` with the method's per-cloud estimates made once for the whole survey
    (`Method.survey_config`, where the method has one: DMF's voxel size W, CSF's cloth start),
    so every file and its halo share them; otherwise `config` as it is. Reads each file's store
    once, and for a method whose labels depend on the whole cloud (`Method.whole_cloud`) its
    halo (`halo_width`), so that what the estimates read is what the files joined into one
    give. `hidden_by`: the terrain whose low outliers the method's run hides (`adaptive.run`),
    left out of the points the estimates see; None: none hidden."""
    hook = method.survey_config
    if hook is None:
        return config
    hidden_by = hidden_by if method.hides_low_outliers else None
    halo_m = halo_width(method, config) if method.whole_cloud else 0.0
    return hook(config, _file_points(catalog, returns, hidden_by, halo_m), catalog.frame)


def survey_terrain(catalog: Catalog, *, returns: str = "all") -> adaptive.Terrain | None:
    """The statistics the method's rules read (`gfjax.adaptive`), of the whole survey as one
    cloud: `adaptive.measure_chunks` over every file's blocks, so they equal those of the files
    joined into one and the survey labels as that file would be (each file's own statistics
    combined, `adaptive.combine`, gave other slopes and relief: PMF then labelled 19 % of
    bcts_1 + bcts_2 cut 3 x 3 otherwise). None when no point is used. Each pass reads every
    store a block at a time, the files side by side: memory holds a block and the measuring grids
    a worker, never a file's points; the first pass writes each block's columns to temporary
    files, which the others read (`_chunks`)."""
    with tempfile.TemporaryDirectory(prefix="gfjax-terrain-") as folder:
        return adaptive.measure_chunks([_chunks(entry, returns, Path(folder) / str(i))
                                        for i, entry in enumerate(catalog.entries)],
                                       name=f"the survey of {len(catalog.entries)} files")


class Settings(NamedTuple):
    """A method's settings for a whole survey (`survey_settings`): `config` and `params`,
    `settled` (`adaptive.Settled`, None when nothing was left to the data), the survey's
    `terrain` (None when the method reads none), `options`, the further keyword arguments of
    the method's `filter` (the terrain, for a method that `takes_terrain`), and `estimated`,
    field -> value of the config that the survey fixed once for every file (`survey_config`)."""

    config: Any
    params: Any
    settled: adaptive.Settled | None
    terrain: adaptive.Terrain | None
    options: dict
    estimated: dict[str, Any] = {}


def survey_settings(method: Method, catalog: Catalog, config, params, *, fixed: Iterable[str] | None,
                    returns: str = "all", whole: bool | None = None) -> Settings:
    """The values a survey's files all share: those that follow the data settled once on the
    survey's terrain (`survey_terrain`, the method's `adapt`) but the fields in `fixed` (None:
    nothing settles, the values stay as given), the terrain itself for a method that
    `takes_terrain` (the vote's voters settle on it whatever the vote's own values), then the
    method's per-cloud estimates made once for the survey (`survey_config`), unless the survey
    runs as one cloud (`whole`; None: as `fits_whole` says), which makes its own."""
    settles = fixed is not None and method.adapt is not None
    terrain = survey_terrain(catalog, returns=returns) if settles or method.takes_terrain else None
    settled = None
    if settles and terrain is not None:
        settled = adaptive.settle_terrain(method.adapt, terrain, config, params, fixed=fixed)
        config, params = settled.config, settled.params
    options = {"terrain": terrain} if method.takes_terrain and terrain is not None else {}
    if whole is None:
        whole = fits_whole(method, config, catalog)
    fixed_config = config if whole else survey_config(method, config, catalog, returns=returns,
                                                      hidden_by=None if settled is None else settled.terrain)
    estimated = {field.name: getattr(fixed_config, field.name) for field in dataclasses.fields(fixed_config)
                 if getattr(fixed_config, field.name) != getattr(config, field.name)}
    return Settings(fixed_config, params, settled, terrain, options, estimated)


def _chunks(entry: Entry, returns: str, spill: Path) -> Callable[[], Iterator[adaptive.Chunk]]:
    """The `adaptive.Chunk`s of a file's blocks, anew at each call: its used points (`use_mask`
    of `returns`) and their last returns, read at the first call from the file's store (a COPC
    file's from the file) and written there, block by block, to the folder `spill` as the
    contiguous columns the passes read, which the later calls read back. Preparing a block's
    columns (its masks, the last returns' rows) cost four times reading them; where the
    folder's disk lacks the room, every call reads the store (a COPC file always spills: it
    has no store)."""
    sizes: list[tuple[int, int]] = []          # (used, last) points of each block spilled
    complete = []                              # [True] once every block is

    def blocks() -> Iterator[adaptive.Chunk]:
        for _, block in entry.blocks():
            args = (block["ignored"], block["return_number"], block["number_of_returns"])
            xyz = block["xyz_m"]
            use, last = use_mask(*args, returns), use_mask(*args, "last")
            # a column, then its rows: a mask over (n, 3) rows gathers three times slower
            columns = [xyz[:, j] for j in range(3)]
            used = tuple(columns) if use.all() else tuple(c[use] for c in columns)
            yield used, (columns[0][last], columns[1][last])

    def spilling() -> Iterator[adaptive.Chunk]:
        shutil.rmtree(spill, ignore_errors=True)           # a pass given up half way
        spill.mkdir()
        sizes.clear()
        for k, (used, last) in enumerate(blocks()):
            with open(spill / f"{k}.f8", "wb") as out:
                for column in (*used, *last):
                    np.ascontiguousarray(column).tofile(out)
            sizes.append((len(used[0]), len(last[0])))
            yield used, last
        complete.append(True)

    def spilled() -> Iterator[adaptive.Chunk]:
        for k, (n_used, n_last) in enumerate(sizes):
            columns = point_store.mapped(spill / f"{k}.f8", np.dtype(np.float64))
            used = tuple(columns[j * n_used:(j + 1) * n_used] for j in range(3))
            yield used, (columns[3 * n_used:3 * n_used + n_last], columns[3 * n_used + n_last:])

    def chunks() -> Iterator[adaptive.Chunk]:
        if complete:
            return spilled()
        # room for this file's columns twice over: the other files spill beside it
        if entry.store is not None and shutil.disk_usage(spill.parent).free < 2 * SPILL_BYTES_PER_POINT * entry.n_points:
            return blocks()
        return spilling()

    return chunks


def filter_file(catalog: Catalog, i: int, cloud: Cloud, filter_fn: Callable, lattice: Lattice | None, *,
                returns: str = "all", halo_m: float = HALO_M) -> tuple[Result, np.ndarray]:
    """File `i` of the catalog (read as `cloud`) filtered with its halo (`filtered`'s step;
    `halo_m`: `halo_width`, for a method without `lattice`).

    Returns:
      `(result, halo_ground_m)`: the `Result` for the file's own points (`ground`,
      `instance_id` cut to them; the diagnostics describe the whole window), and the halo's
      points labelled ground, float64 `(k, 3)` [m] (they give the file's DTM its border
      cells: `gfjax.dtm.build(context_xyz=...)`).
    """
    points = window(catalog, i, cloud, lattice, halo_m)
    n = cloud.n_points
    result = filter_fn(points, returns=returns, core=np.arange(points.n_points) < n)
    ground = np.asarray(result.ground)
    instance_id = None if result.instance_id is None else np.asarray(result.instance_id)[:n]
    halo_ground_m = points.xyz_m[n:][ground[n:]]
    del points
    # the window's many small blocks are free now, and glibc would keep them for the next
    # file's, scattered where that file's blocks fit only in part: each file would then add
    # to a heap that grows with the survey (`gfjax.heap`)
    heap.trim()
    return result._replace(ground=ground[:n], instance_id=instance_id), halo_ground_m


def fits_whole(method: Method, config, catalog: Catalog) -> bool:
    """Whether the survey is filtered as one cloud: `method`'s labels depend on the whole cloud
    (`Method.whole_cloud`), and the survey's points in memory together with the method's largest
    raster over the survey's frame fit the memory budget (`gfjax.limits`; this machine's)."""
    if not method.whole_cloud or catalog.frame is None:
        return False
    span = np.asarray(catalog.frame.upper_m, np.float64) - np.asarray(catalog.frame.origin_m[:2], np.float64)
    n_points = sum(entry.n_points for entry in catalog.entries)
    rasters = [estimate.n_bytes for estimate in config.memory_estimates((float(span[0]), float(span[1])))]
    points = n_points * (limits.IN_MEMORY_BYTES_PER_POINT + STORE.itemsize)
    return points + max(rasters, default=0.0) <= limits.memory_budget_bytes()


def survey_labels(catalog: Catalog, filter_fn: Callable, *, returns: str = "all") -> Result:
    """Every file's points, in catalog order, as one cloud, filtered once: the `Result` over all
    of them, without diagnostics (`file_of_survey` cuts out a file's).

    The cloud takes no frame: its own box is the survey's frame, and the method treats it
    exactly as one file of the whole survey (groups of points far apart included)."""
    records = np.concatenate([entry.records() for entry in catalog.entries])
    result = filter_fn(Points.from_records(records, "the survey"), returns=returns)
    return result._replace(diagnostics=None)


def file_of_survey(catalog: Catalog, filter_fn: Callable, whole: Result, i: int, *,
                   context: bool = True) -> tuple[Result, np.ndarray]:
    """File `i`'s part of `survey_labels`' result, as `filter_file` gives it: `(result,
    halo_ground_m)`, the other files' ground points within `HALO_M` of its box, float64
    `(k, 3)` [m] (none without `context`: a DTM needs them, and finding them reads the
    neighbours' stores). (`filter_fn` is unused: the signature of a survey task.)"""
    starts = np.cumsum([0, *(entry.n_points for entry in catalog.entries)])
    ground = np.asarray(whole.ground, bool)
    own = slice(starts[i], starts[i + 1])
    instance_id = None if whole.instance_id is None else np.asarray(whole.instance_id)[own]
    halo = np.empty((0, 3), np.float64)
    entry = catalog.entries[i]
    if context and entry.frame is not None:
        halo = ground_near(catalog, i, *halo_region(entry.frame, catalog.frame, None),
                           lambda j: ground[starts[j]:starts[j + 1]])
    return Result(ground=ground[own], diagnostics=None, instance_id=instance_id), halo
