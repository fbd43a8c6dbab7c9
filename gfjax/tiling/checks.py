"""The checks at the top of every method's `filter`: its options, its tiling, its memory.

Every method (tiled or not) checks its arguments here before any work: the cloud is a
`CloudView`, `config` and `params` are the method's types and in range (`checked_options`), the
tiling is a `Tiling` whose cores hold a cell (`checked_tiling`, `lattice_of`), and the rasters
its settings imply over the points fit the memory budget (`check_memory`). Each failure is an
`InputError` naming the cloud.

Host-side Python; nothing here is traced.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import numpy as np

from gfjax import limits
from gfjax.errors import InputError
from gfjax.io import columns
from gfjax.io.cloud import CloudView
from gfjax.tiling import tiles as tiles_lib

__all__ = ["Estimates", "checked_options", "check_memory", "checked_tiling", "lattice_of"]

ConfigT = TypeVar("ConfigT")

ParamsT = TypeVar("ParamsT")

Estimates = Callable[[tuple[float, float] | None], list[limits.Estimate]]
"""`estimates(extent_m)`: a method's `Config.memory_estimates` with its settings bound."""


def checked_tiling(tiling: tiles_lib.Tiling | None) -> tiles_lib.Tiling:
    """A method's `tiling` argument: `Tiling()` for None; not a `Tiling` raises `InputError`."""
    tiling = tiles_lib.Tiling() if tiling is None else tiling
    if not isinstance(tiling, tiles_lib.Tiling):
        raise InputError(f"tiling must be a gfjax.Tiling, got {type(tiling).__name__}")
    return tiling


def lattice_of(tiling: tiles_lib.Tiling | None, cell_m: float, *, name: str = "") -> tiles_lib.Lattice:
    """`tiling` (`checked_tiling`) at a method's raster cell `cell_m` [m]; a core smaller than
    a cell raises `InputError` (naming `name`, a cloud)."""
    tiling = checked_tiling(tiling)
    try:
        return tiling.lattice(cell_m)
    except ValueError as err:
        raise InputError(f"{name}: {err}" if name else str(err)) from None


def checked_options(cloud: object, config: ConfigT | None, params: ParamsT | None, returns: str, *,
                    config_type: type[ConfigT], params_type: type[ParamsT],
                    package: str) -> tuple[ConfigT, ParamsT, np.ndarray]:
    """The checks at the top of a method's `filter`: defaults, types, `params.check()`, returns.

    Args:
      cloud: the cloud to filter.
      config, params: the caller's settings, None for the defaults `config_type()`, `params_type()`.
      returns: "all" or "last" (`Cloud.filter_mask`).
      config_type, params_type: the method's `Config` and `Params` classes.
      package: the method's package for messages, e.g. "gfjax.smrf".

    Returns:
      `(config, params, use)`: `use` bool `(n,)`, the points to filter.

    Raises:
      InputError: not a cloud, a config or params of the wrong type, a params out of range (the message
        names the cloud), a bad `returns`. The rasters are checked against the memory budget
        once the points are known (`check_memory`, `driver.filter_groups`).
    """
    if not isinstance(cloud, CloudView):
        raise InputError(f"{package}.filter: expected a gfjax Cloud (or survey.Points), got {type(cloud).__name__}")
    config = config_type() if config is None else config
    params = params_type() if params is None else params
    if not isinstance(config, config_type):
        raise InputError(f"config must be a {package}.Config, got {type(config).__name__}")
    if not isinstance(params, params_type):
        raise InputError(f"params must be a {package}.Params, got {type(params).__name__}")
    try:
        params.check()
        use = cloud.filter_mask(returns)
    except ValueError as err:
        raise InputError(f"{cloud.name}: {err}") from None
    return config, params, use


def check_memory(name: str, estimates: Estimates | None, xy_m: np.ndarray | None) -> None:
    """Raise `InputError` naming `name` when `estimates` (None: no check) puts the rasters over
    points `xy_m` `(n, 2)` [m] (None: only those the settings fix, such as a batch of tiles)
    over the memory budget (`gfjax.limits`)."""
    if estimates is None or (xy_m is not None and len(xy_m) == 0):
        return
    extent = None
    if xy_m is not None:
        span = columns.highs(xy_m) - columns.lows(xy_m)
        extent = (float(span[0]), float(span[1]))
    try:
        limits.check_memory(estimates(extent))
    except ValueError as err:
        raise InputError(f"{name}: {err}") from None
