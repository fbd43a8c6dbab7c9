"""DMF's numbers fitted to labelled files by grid search (Wu et al. 2025, Eq. 1 and Sec. 2.6).

The numbers that decide DMF's labels are the voxel-size factor `v0` (Eq. 1: `W = ceil(v0 *
mean nearest-neighbour distance)`, which sets every raster and layer), the half-width of the
max filter of Eq. 2 `max_filter_px`, the share of an equal-layer region's cells in NGNEM_BI
that makes it non-ground `rc_min_share` (Sec. 2.5), the lowering of the
support nodes `v1` (Sec. 2.6; it acts through the M-nearest rule only, so it is searched only
when `Config.final_rule` uses that rule), and the height rule's threshold above the support
surface, `height_threshold_m + height_threshold_w * W` (`Params`). W is a whole number of
metres and every stage after it runs on the host or in bounded while loops, so no gradient
reaches `v0`; the final rule is a hard cut of host-computed heights. They are therefore
searched on a grid (`GRID`, every combination) with the filter's own stages: each sample is
prepared once per `v0` (`gfjax.dmf.filter.prepare`: steps 1-6) and each candidate runs step 7
(`extract.extract_ground`). The choice and its guard are `gfjax.tune.search`'s.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping, Sequence

import numpy as np

from gfjax.dmf import extract
from gfjax.dmf.config import Config, Params
from gfjax.dmf.filter import prepare
from gfjax.params import declared_defaults
from gfjax.tune import search
from gfjax.tune.problem import Sample

__all__ = ["GRID", "V1_VALUES", "NOTE", "UNITS", "default_grid", "candidates", "labels", "TUNER"]

GRID: dict[str, tuple[float, ...]] = {
    "v0": (1.0, 1.5, 2.0, 2.5, 3.0),
    "max_filter_px": (1, 2, 3),
    "rc_min_share": (0.5, 0.75, 1.0),
    "height_threshold_m": (0.0, 0.25, 0.5),
    "height_threshold_w": (0.0, 0.1, 0.15, 0.2, 0.25, 0.4),
}
_PREPARED_KEYS = ("v0", "max_filter_px", "rc_min_share")     # each value: steps 1-6 again
V1_VALUES = (1.0, 1.5, 2.0, 3.0)        # added to the grid when the final rule uses the M-nearest search
UNITS = {"v0": "1 (W over the mean nearest-neighbour distance)", "max_filter_px": "cells", "rc_min_share": "1",
         "v1": "W", "height_threshold_m": "m", "height_threshold_w": "W"}
NOTE = ("v0 sets the voxel size W = ceil(v0 * mean nearest-neighbour distance), a whole number of "
        "metres that sets every raster; v1 and the height threshold act in host code at the final "
        "rule: no gradient, so every combination of the grid is tried (exhaustive grid search)")
_PARAMS_KEYS = ("height_threshold_m", "height_threshold_w")


def _defaults(config: Config) -> dict[str, float]:
    declared = declared_defaults(Params)
    keys = {k: float(getattr(config, k)) for k in _PREPARED_KEYS}
    if config.final_rule != "height":
        keys["v1"] = float(config.v1)
    return keys | {k: float(declared[k]) for k in _PARAMS_KEYS}


def default_grid(config: Config) -> dict[str, tuple[float, ...]]:
    """`GRID`, with `v1` when `config.final_rule` reads the lowered support nodes."""
    return GRID | ({"v1": V1_VALUES} if config.final_rule != "height" else {})


def candidates(config: Config, grid: Mapping[str, Sequence[float]] | None = None) -> tuple[list[dict[str, float]], int]:
    """Every combination of `grid` (default `default_grid(config)`; `search.grid_candidates`)
    and the index of the defaults' combination, grouped by the values steps 1-6 read (one
    preparation each)."""
    return search.grid_candidates(_defaults(config), default_grid(config) if grid is None else grid)


def _config(config: Config, combo: Mapping[str, float]) -> Config:
    """`config` with the combination's `Config` values (whole numbers for integer fields)."""
    values = {k: v for k, v in combo.items() if k not in _PARAMS_KEYS}
    return dataclasses.replace(config, **{k: int(v) if isinstance(getattr(config, k), int) else v
                                          for k, v in values.items()})


def labels(sample: Sample, config: Config, combos: Sequence[Mapping[str, float]]) -> Iterator[np.ndarray]:
    """DMF's ground (bool `(n,)`) on `sample` with each combination in turn, run as
    `gfjax.dmf.filter` runs a cloud (unused points are never ground): the defaults' labels are
    the plain filter's, point for point (tested)."""
    ground = np.zeros(len(sample.xyz_m), bool)
    prep, prepared_key = None, None
    for combo in combos:
        cfg = _config(config, combo)
        if sample.use.any():
            key = tuple(combo[k] for k in _PREPARED_KEYS)
            if key != prepared_key:
                prep, prepared_key = prepare(sample, sample.use, cfg), key
            params = Params(**{k: combo[k] for k in _PARAMS_KEYS})
            _, ground[sample.use], _ = extract.extract_ground(prep.local, prep.vox, prep.object_cell, prep.in_ndng,
                                                              dataclasses.replace(prep.config, v1=cfg.v1), params,
                                                              points_tree=prep.tree)
        yield ground.copy()


TUNER = search.GridTuner("dmf", Config, default_grid, candidates, labels, UNITS, NOTE)
