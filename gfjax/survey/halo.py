"""A file of a survey with its halo: the neighbours' points its tiles' windows can reach.

A tiled method (a `Config` with `tile_size_m`, `buffer_m` and `cell_m`) lays its tiles on
the survey's frame, so the windows of the tiles holding a file's points are known before
filtering: the file's halo is every point of the other files inside them (plus a cell), and
those windows then hold exactly the points they would hold in one file of the whole survey:
the file's labels are the same. A method that does not tile gets the points within
`HALO_M` of the file's bounding box as context, which removes most, not all, of the seam.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import ModuleType

import numpy as np

from gfjax import methods
from gfjax.io import las as las_io
from gfjax.io.cloud import Cloud, use_mask
from gfjax.io.tiles import Frame
from gfjax.result import Result
from gfjax.survey.catalog import Catalog, index

HALO_M = 50.0           # context around a file for methods that do not tile [m]


@dataclasses.dataclass(frozen=True, eq=False)
class Points:
    """The views a filter reads from a cloud (`Cloud.xyz_m`, `filter_mask`, ...), as plain arrays.

    Attributes:
      xyz_m: float64 `(n, 3)` [m].
      classification, return_number, number_of_returns: uint8 `(n,)`.
      ignored: bool `(n,)` noise or withheld.
      name: for messages.
      frame: the tiling frame (`Frame`), or None.
    """

    xyz_m: np.ndarray
    classification: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    ignored: np.ndarray
    name: str = "<memory>"
    frame: Frame | None = None

    @property
    def n_points(self) -> int:
        return int(self.xyz_m.shape[0])

    def filter_mask(self, returns: str = "all") -> np.ndarray:
        return use_mask(self.ignored, self.return_number, self.number_of_returns, returns)


def halo_region(box: Frame, frame: Frame, config) -> tuple[np.ndarray, np.ndarray]:
    """The x-y box `(lo (2,), hi (2,))` [m] whose points can share a window with a point of `box`.

    Tiled methods: the windows of the tiles whose cores meet `box`, laid on `frame` as
    `gfjax.io.tiles.split` lays them, grown by one cell; other methods: `box` grown by `HALO_M`.
    """
    lo, hi = np.asarray(box.origin_m[:2], np.float64), np.asarray(box.upper_m, np.float64)
    if not all(hasattr(config, name) for name in ("tile_size_m", "buffer_m", "cell_m")):
        return lo - HALO_M, hi + HALO_M
    tile, cell = config.tile_size_m, config.cell_m
    origin = np.asarray(frame.origin_m[:2], np.float64)
    core_px = tile / cell
    buffer_px = math.ceil(config.buffer_m / cell - 1e-9)
    first = np.floor((lo - origin) / tile)
    last = np.floor((hi - origin) / tile)
    lo_px = np.floor(first * core_px) - buffer_px - 1
    hi_px = np.ceil((last + 1) * core_px) + buffer_px + 1
    return origin + lo_px * cell, origin + hi_px * cell


def window(catalog: Catalog, i: int, cloud: Cloud, config) -> Points:
    """File `i` of the catalog (read as `cloud`) followed by its halo, on the survey's frame."""
    entry = catalog.entries[i]
    parts = [dict(xyz_m=cloud.xyz_m, classification=cloud.classification, return_number=cloud.return_number,
                  number_of_returns=cloud.number_of_returns, ignored=cloud.ignored)]
    if entry.frame is not None:
        lo, hi = halo_region(entry.frame, catalog.frame, config)
        for j, other in enumerate(catalog.entries):
            if j == i or other.frame is None or np.any(other.frame.origin_m[:2] > hi) or np.any(other.frame.upper_m < lo):
                continue
            records = other.records()
            xy = records["xyz_m"][:, :2]
            take = np.flatnonzero(np.all((xy >= lo[None, :]) & (xy <= hi[None, :]), axis=1))
            if take.size:
                chosen = records[take]
                parts.append({name: np.asarray(chosen[name]) for name in parts[0]})
    fields = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
    return Points(**fields, name=cloud.name, frame=catalog.frame)


def survey_config(method: ModuleType, config, catalog: Catalog, *, returns: str = "all"):
    """`config` with the method's per-cloud estimates made once for the whole survey
    (`method.survey_config`, where the method has one: DMF's voxel size W), so every file and
    its halo share them; otherwise `config` as it is. Reads each file's store once."""
    hook = getattr(method, "survey_config", None)
    if hook is None:
        return config

    def clouds() -> Iterator[np.ndarray]:
        for entry in catalog.entries:
            records = entry.records()
            used = use_mask(records["ignored"], records["return_number"], records["number_of_returns"], returns)
            yield np.asarray(records["xyz_m"][used])

    return hook(config, clouds())


def filtered(paths: Sequence[str | Path], method: str | ModuleType, folder: str | Path, *, config=None, params=None,
             returns: str = "all", units: str | None = None, **options) -> Iterator[tuple[Cloud, Result]]:
    """Each file of a survey and its `Result`, filtered with its halo on the survey's frame.

    ```python
    for cloud, result in gfjax.survey.filtered(paths, "dmf", tmp_folder):
        ...                                   # result.ground: the file's own points
    ```

    Args:
      paths: the survey's files.
      method: a method name (`gfjax.methods.METHODS`) or package (`gfjax.dmf`).
      folder: a private temporary folder for the catalog's stores.
      config, params: the method's settings (default: its defaults); `config`'s tiling sets
        the halo, and its per-cloud estimates are made once for the survey (`survey_config`).
      returns: "all" or "last".
      units: `--units` override.
      options: further keyword arguments of the method's `filter` (SparseGF's `model`).

    Yields:
      `(cloud, result)` per file in the order of `paths`; `result.ground` covers the file's
      own points only.
    """
    module = methods.get(method) if isinstance(method, str) else method
    config = module.Config() if config is None else config
    catalog = index(paths, folder, returns=returns, units=units)
    config = survey_config(module, config, catalog, returns=returns)

    def filter_fn(points: Points, returns: str) -> Result:
        return module.filter(points, config=config, params=params, returns=returns, **options)

    for i, entry in enumerate(catalog.entries):
        cloud = las_io.read(entry.path, units=units)
        yield cloud, filter_file(catalog, i, cloud, filter_fn, config, returns=returns)[0]


def filter_file(catalog: Catalog, i: int, cloud: Cloud, filter_fn: Callable, config, *,
                returns: str = "all") -> tuple[Result, np.ndarray]:
    """File `i` of the catalog (read as `cloud`) filtered with its halo (`filtered`'s step).

    Returns:
      `(result, halo_ground_m)`: the `Result` for the file's own points (`ground`,
      `instance_id` cut to them; the diagnostics describe the whole window), and the halo's
      points labelled ground, float64 `(k, 3)` [m] (they give the file's DTM its border
      cells: `gfjax.dtm.build(context_xyz=...)`).
    """
    points = window(catalog, i, cloud, config)
    result = filter_fn(points, returns=returns)
    n = cloud.n_points
    ground = np.asarray(result.ground)
    instance_id = None if result.instance_id is None else np.asarray(result.instance_id)[:n]
    return result._replace(ground=ground[:n], instance_id=instance_id), points.xyz_m[n:][ground[n:]]
