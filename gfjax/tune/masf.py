"""MASF's settings fitted to labelled files by grid search (Cao et al. 2024, Eqs. 1-2).

MASF has four numbers a user tunes by hand, and the paper gives them per sample (Table 3):
the top of the alpha pyramid `alpha_max_m` and its step `alpha_step_m` (Eq. 1: which potential
ground points make each layer) and the densification thresholds `st` and `ft_m` (Eq. 2:
`DT_k = st * alpha_k + ft_m`). None has a gradient: the pyramid changes which points exist in
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

from gfjax.io import groups
from gfjax.masf.config import Config, Params
from gfjax.masf.filter import densify, prepare, pyramid
from gfjax.params import declared_defaults
from gfjax.tune import search
from gfjax.tune.problem import Sample

__all__ = ["GRID", "CONFIG_KEYS", "PARAMS_KEYS", "NOTE", "UNITS", "default_grid", "candidates", "labels", "METHOD"]

CONFIG_KEYS = ("alpha_max_m", "alpha_step_m")      # set the pyramid (`Config`)
PARAMS_KEYS = ("st", "ft_m")                       # set the densification (`Params`)
# Table 3's alpha_max and step values, and ST and FT around the paper's.
GRID: dict[str, tuple[float, ...]] = {
    "alpha_max_m": (10.0, 15.0, 20.0, 25.0),
    "alpha_step_m": (1.0, 2.0, 4.0, 9.0),
    "st": (0.01, 0.03, 0.05, 0.10, 0.15),
    "ft_m": (0.3, 0.5, 0.7),
}
UNITS = {"alpha_max_m": "m", "alpha_step_m": "m", "st": "1 (rise over run)", "ft_m": "m"}
NOTE = ("alpha_max_m and alpha_step_m change which points make each layer of the pyramid, and "
        "st and ft_m act through a TIN grown by scipy triangulations on the host: no gradient, "
        "so every combination of the grid is tried (exhaustive grid search)")


def _defaults(config: Config) -> dict[str, float]:
    """The config's pyramid and `Params`' declared defaults (the numbers, not their float32)."""
    declared = declared_defaults(Params)
    return {k: float(getattr(config, k)) for k in CONFIG_KEYS} | {k: float(declared[k]) for k in PARAMS_KEYS}


def default_grid(config: Config) -> dict[str, tuple[float, ...]]:
    """`GRID` (the same for every config)."""
    del config
    return dict(GRID)


def candidates(config: Config, grid: Mapping[str, Sequence[float]] | None = None) -> tuple[list[dict[str, float]], int]:
    """Every combination of `grid` (default `GRID`; `search.grid_candidates`) whose pyramid
    `Config` accepts (alpha_max at least alpha_min), and the index of the defaults' combination."""
    return search.grid_candidates(_defaults(config), default_grid(config) if grid is None else grid,
                                  keep=lambda c: c["alpha_max_m"] >= config.min_alpha_m)


def _settings(config: Config, combo: Mapping[str, float]) -> tuple[Config, Params]:
    return (dataclasses.replace(config, **{k: combo[k] for k in CONFIG_KEYS}),
            Params(**{k: combo[k] for k in PARAMS_KEYS}))


def labels(sample: Sample, config: Config, combos: Sequence[Mapping[str, float]]) -> Iterator[np.ndarray]:
    """MASF's ground (bool `(n,)`) on `sample` with each combination in turn, run as
    `gfjax.masf.filter` runs a cloud (far groups moved together first, the same stages; unused
    points are never ground): the defaults' labels are the plain filter's, point for point
    (tested)."""
    used = np.flatnonzero(sample.use)
    reach_m = 2 * max(c["alpha_max_m"] for c in combos)
    xyz, _ = groups.compacted(sample.xyz_m, max(groups.GAP_M, reach_m), use=sample.use)
    prep = prepare(xyz[used], config)
    ground = np.zeros(len(sample.xyz_m), bool)
    layers, pyramid_of = None, None
    for combo in combos:
        cfg, params = _settings(config, combo)
        if len(prep.pre.index):
            key = (cfg.alpha_max_m, cfg.alpha_step_m)
            if key != pyramid_of:
                layers, pyramid_of = pyramid(prep, cfg), key
            ground[used] = densify(prep, layers, cfg, params).ground
        yield ground.copy()


METHOD = search.Searched("masf", Config, default_grid, candidates, labels, UNITS, NOTE)
