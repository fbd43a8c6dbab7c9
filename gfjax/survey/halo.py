"""A file of a survey with its halo: the neighbours' points its tiles' windows can reach.

A tiled method (SMRF, PMF: `gfjax.methods.lattice` gives its tiling at its cell) lays its tiles on
the survey's frame, so the windows of the tiles holding a file's points are known before
filtering: the file's halo is every point of the other files inside them (plus a cell), and
those windows then hold exactly the points they would hold in one file of the whole survey:
the file's labels are the same. A method that does not tile gets the points within
`HALO_M` of the file's bounding box as context, which removes most, not all, of the seam.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from types import ModuleType

import numpy as np

from gfjax.io.cloud import Cloud, Points, use_mask
from gfjax.io.tiles import Frame, Lattice
from gfjax.result import Result
from gfjax.survey.catalog import Catalog

HALO_M = 50.0           # context around a file for methods that do not tile [m]


def halo_region(box: Frame, frame: Frame, lattice: Lattice | None) -> tuple[np.ndarray, np.ndarray]:
    """The x-y box `(lo (2,), hi (2,))` [m] whose points can share a window with a point of `box`.

    A tiled method (`lattice`, its tiling at its cell): the windows of the tiles whose cores
    meet `box`, laid on `frame` as `gfjax.io.tiles.split` lays them, grown by one cell; other
    methods (None): `box` grown by `HALO_M`.
    """
    lo, hi = np.asarray(box.origin_m[:2], np.float64), np.asarray(box.upper_m, np.float64)
    if lattice is None:
        return lo - HALO_M, hi + HALO_M
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


def window(catalog: Catalog, i: int, cloud: Cloud, lattice: Lattice | None) -> Points:
    """File `i` of the catalog (read as `cloud`) followed by its halo, on the survey's frame."""
    entry = catalog.entries[i]
    parts = [dict(xyz_m=cloud.xyz_m, classification=cloud.classification, return_number=cloud.return_number,
                  number_of_returns=cloud.number_of_returns, ignored=cloud.ignored)]
    if entry.frame is not None:
        lo, hi = halo_region(entry.frame, catalog.frame, lattice)
        for j, other in enumerate(catalog.entries):
            if j == i or not overlaps(other.frame, lo, hi):
                continue
            take, chosen = other.within(lo, hi)
            if take.size:
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
            parts = [block["xyz_m"][use_mask(block["ignored"], block["return_number"], block["number_of_returns"],
                                              returns)] for _, block in entry.blocks()]
            yield np.concatenate(parts) if parts else np.empty((0, 3))

    return hook(config, clouds())


def filter_file(catalog: Catalog, i: int, cloud: Cloud, filter_fn: Callable, lattice: Lattice | None, *,
                returns: str = "all") -> tuple[Result, np.ndarray]:
    """File `i` of the catalog (read as `cloud`) filtered with its halo (`filtered`'s step).

    Returns:
      `(result, halo_ground_m)`: the `Result` for the file's own points (`ground`,
      `instance_id` cut to them; the diagnostics describe the whole window), and the halo's
      points labelled ground, float64 `(k, 3)` [m] (they give the file's DTM its border
      cells: `gfjax.dtm.build(context_xyz=...)`).
    """
    points = window(catalog, i, cloud, lattice)
    result = filter_fn(points, returns=returns)
    n = cloud.n_points
    ground = np.asarray(result.ground)
    instance_id = None if result.instance_id is None else np.asarray(result.instance_id)[:n]
    return result._replace(ground=ground[:n], instance_id=instance_id), points.xyz_m[n:][ground[n:]]
