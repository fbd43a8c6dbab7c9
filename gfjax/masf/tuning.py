"""MASF's settings fitted to labelled files by grid search (Cao et al. 2024, Eqs. 1-2).

MASF has four numbers a user tunes by hand, and the paper gives them per sample (Table 3):
the top of the alpha pyramid `alpha_max_m` and its step `alpha_step_m` (Eq. 1: which potential
ground points make each layer) and the densification thresholds `st` and `ft_m` (Eq. 2:
`DT_k = st * alpha_k + ft_m`); for one sample (samp42, a railway station) it also adds a top
layer of alpha 90 m (`alpha_top_m`, Sec. 3.3.1), searched here as a fifth key (`NO_TOP`: no
top layer). None has a gradient: the pyramid changes which points exist in
each layer, and the densification grows a TIN by scipy triangulations on the host. So they
are searched on a grid (`GRID`, every combination: the paper's values of Table 3 are among
them), with the filter's own stages (`gfjax.masf.filter.prepare`, `pyramid`, `densify`): each
sample is preprocessed and triangulated once, each pyramid built once, and each candidate
densifies. The choice and its guard are `gfjax.tune.search`'s.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping, Sequence

import numpy as np

from gfjax.limits import Range
from gfjax.masf.config import Config, Params
from gfjax.masf.filter import Prepared, densify, prepare, pyramid
from gfjax.params import declared_defaults
from gfjax.tiling import groups
from gfjax.tune import search
from gfjax.tune.problem import Sample

__all__ = ["GRID", "CONFIG_KEYS", "PARAMS_KEYS", "NO_TOP", "NOTE", "UNITS", "default_grid", "candidates", "labels",
           "TUNER"]

CONFIG_KEYS = ("alpha_max_m", "alpha_step_m", "alpha_top_m")      # set the pyramid (`Config`)
PARAMS_KEYS = ("st", "ft_m")                       # set the densification (`Params`)
NO_TOP = 0.0          # alpha_top_m of a candidate without a top layer (`Config.alpha_top_m` None)
# Table 3's alpha_max and step values, its top layer, and ST and FT around the paper's.
GRID: dict[str, tuple[float, ...]] = {
    "alpha_max_m": (10.0, 15.0, 20.0, 25.0),
    "alpha_step_m": (1.0, 2.0, 4.0, 9.0),
    "alpha_top_m": (NO_TOP, 90.0),
    "st": (0.01, 0.03, 0.05, 0.10, 0.15),
    "ft_m": (0.3, 0.5, 0.7),
}
UNITS = {"alpha_max_m": "m", "alpha_step_m": "m", "alpha_top_m": "m", "st": "1 (rise over run)", "ft_m": "m"}
# alpha_top_m in a grid: NO_TOP or a positive value; a candidate whose top layer is not above its
# alpha_max_m is left out (`candidates`)
GRID_RANGES = {"alpha_top_m": Range(0, 100_000, unit="m", extra=f"{NO_TOP:g}: no top layer; else > alpha_max_m")}
NOTE = ("alpha_max_m, alpha_step_m and alpha_top_m change which points make each layer of the pyramid, and "
        "st and ft_m act through a TIN grown by scipy triangulations on the host: no gradient, "
        "so every combination of the grid is tried (exhaustive grid search)")


def _defaults(config: Config) -> dict[str, float]:
    """The config's pyramid and `Params`' declared defaults (the numbers, not their float32)."""
    declared = declared_defaults(Params)
    pyramid = {k: getattr(config, k) for k in CONFIG_KEYS}
    return ({k: NO_TOP if v is None else float(v) for k, v in pyramid.items()}
            | {k: float(declared[k]) for k in PARAMS_KEYS})


def default_grid(config: Config) -> dict[str, tuple[float, ...]]:
    """`GRID` (the same for every config)."""
    del config
    return dict(GRID)


def candidates(config: Config, grid: Mapping[str, Sequence[float]] | None = None) -> tuple[list[dict[str, float]], int]:
    """Every combination of `grid` (default `GRID`; `search.grid_candidates`) whose pyramid
    `Config` accepts (alpha_max at least alpha_min, a top layer above alpha_max), and the index
    of the defaults' combination."""
    def keep(c):
        return c["alpha_max_m"] >= config.min_alpha_m and (c["alpha_top_m"] == NO_TOP or c["alpha_top_m"] > c["alpha_max_m"])

    return search.grid_candidates(_defaults(config), default_grid(config) if grid is None else grid, keep=keep)


def values(combo: Mapping[str, float]) -> dict[str, float]:
    """A candidate as params.json `values` (no `alpha_top_m` where it has no top layer)."""
    return {k: float(v) for k, v in combo.items() if not (k == "alpha_top_m" and v == NO_TOP)}


def _settings(config: Config, combo: Mapping[str, float]) -> tuple[Config, Params]:
    pyramid = {k: combo[k] for k in CONFIG_KEYS}
    pyramid["alpha_top_m"] = None if pyramid["alpha_top_m"] == NO_TOP else pyramid["alpha_top_m"]
    return dataclasses.replace(config, **pyramid), Params(**{k: combo[k] for k in PARAMS_KEYS})


def labels(sample: Sample, config: Config, combos: Sequence[Mapping[str, float]]) -> Iterator[np.ndarray]:
    """MASF's ground (bool `(n,)`) on `sample` with each combination in turn, run as
    `gfjax.masf.filter` runs a cloud (groups of points far apart each alone, a lone point
    ground: `gfjax.tiling.driver.filter_groups`; the same stages; unused points are never ground):
    the defaults' labels are the plain filter's, point for point (tested). Each group is
    prepared once per separating gap; a group's pyramid is built again only when the alpha
    settings change from one combination to the next."""
    used = np.flatnonzero(sample.use)
    parts: dict[float, list[tuple[np.ndarray, Prepared | None]]] = {}
    pyramids: dict[tuple[float, int], tuple[tuple, np.ndarray]] = {}
    for combo in combos:
        cfg, params = _settings(config, combo)
        gap = max(groups.GAP_M, cfg.reach_m)
        if gap not in parts:
            found = groups.members(sample.xyz_m[used, :2], gap, index=used) if len(used) else None
            parts[gap] = [(index, prepare(sample.xyz_m[index], config) if len(index) > 1 else None)
                          for index in (found or [used])]
        ground = np.zeros(len(sample.xyz_m), bool)
        for part, (index, prep) in enumerate(parts[gap]):
            if prep is None:                  # a lone point: a cloud of one point is ground
                ground[index] = True
                continue
            if not len(prep.pre.index):
                continue
            key = (cfg.alpha_max_m, cfg.alpha_step_m, cfg.alpha_top_m)
            if pyramids.get((gap, part), (None,))[0] != key:
                pyramids[(gap, part)] = key, pyramid(prep, cfg)
            ground[index] = densify(prep, pyramids[(gap, part)][1], cfg, params).ground
        yield ground


TUNER = search.GridTuner("masf", Config, default_grid, candidates, labels, UNITS, NOTE, values=values,
                         grid_ranges=GRID_RANGES)
