"""What the tuning loop needs to know of a method: its bounds, its parameter-free preparation,
its relaxed (or hard) ground weight, and its static grid parameter (SPEC section 7).

A `GradientTuner` is a static argument of the jitted losses (hashed by identity: use the module
constants `SMRF`, `PMF` and `CSF`). The values vector `(p,)` is ordered as `GradientTuner.bounds`.

* SMRF (`gfjax.tune.smrf`): slope, threshold_m, scalar fitted; `window_m` searched on a grid
  (`static="window_m"`), its openings prepared once up to the largest window.
* PMF (`gfjax.tune.pmf`): slope, initial_distance_m, max_distance_m fitted; the window
  series stays the config's (`static=None`): the loop's single "grid value" is the config's
  `max_window_m`, reported but never written to params.json.
* CSF (`gfjax.tune.csf`): class_threshold_m fitted (values vector `(1,)`); time step and
  rigidness act through the cloth simulation's while loop (no reverse-mode gradient), so
  they are searched on a grid of cloths (`static="cloth"`, codes `10 * rigidness + time_step`),
  each simulated once per sample (`prepare_samples`, whole samples instead of tiles).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from gfjax import csf as csf_method
from gfjax import pmf as pmf_method
from gfjax import smrf as smrf_method
from gfjax.tune import csf as tcsf
from gfjax.tune import pmf as tpmf
from gfjax.tune import smrf as tsmrf
from gfjax.tune.params import Bound

__all__ = ["GradientTuner", "SMRF", "PMF", "CSF", "METHODS", "get"]


@dataclasses.dataclass(frozen=True, eq=False)
class GradientTuner:
    """A tunable method.

    Attributes:
      name: the method's name in `gfjax.methods` and params.json.
      bounds: fitted scalars, their defaults and bounds (the values vector, `(p,)`).
      units: unit of every value written to params.json.
      config_type: the method's static `Config` class.
      static: name of the grid-searched static parameter ("window_m") or None.
      grid: default grid of the static parameter (empty when `static` is None).
      prepare_tile: `(xyz, valid, hw, *, config, shape) -> prepared` (unjitted); None when
        `prepare_samples` prepares whole samples.
      ground_weight: `(prep, values (p,), *, config, static_px, temperature) -> (n,)`.
      static_px: `(config, value) -> int` traced count for `ground_weight` (0 if unused).
      default_static: `(config) -> float` the static parameter's default (the plain filter's).
      prepared_config: `(config, grid) -> config` the config the preparation runs under.
      prepare_samples: None (tiles), or `(samples, config, *, max_batch) -> [(prep, ref, cloud,
        core_index, shape)]` for a method that filters whole clouds (CSF).
      static_values: None (params.json gets `{static: value}`), or `(value) -> {key: value}`.
      static_note: why the static parameter is searched on a grid (params.json).
    """

    name: str
    bounds: tuple[Bound, ...]
    units: dict
    config_type: type
    static: str | None
    grid: tuple[float, ...]
    prepare_tile: Callable | None
    ground_weight: Callable
    static_px: Callable
    default_static: Callable
    prepared_config: Callable
    prepare_samples: Callable | None = None
    static_values: Callable | None = None
    static_note: str = "loop count of the progressive opening: grid search"

    @property
    def defaults(self) -> np.ndarray:
        """float32 `(3,)` the plain filter's defaults, ordered as `bounds`."""
        return np.asarray([b.default for b in self.bounds], np.float32)

    def __reduce__(self):
        """Pickled by name (a problem cached to disk refers to the module's constant)."""
        return (get, (self.name,))

    def grid_values(self, config, requested: tuple[float, ...] | None) -> tuple[float, ...]:
        """The static values a fit searches: `requested` (or `grid`) for a grid method, else
        the config's own value."""
        if self.static is None:
            return (float(self.default_static(config)),)
        if requested:
            return tuple(requested)
        prepared = getattr(config, "cloths", None)          # a CSF problem's own grid
        return tuple(prepared) if prepared else self.grid

    def params_values(self, value: float) -> dict:
        """The params.json entries of a static grid value."""
        return self.static_values(value) if self.static_values else {self.static: float(value)}


def _smrf_weight(prep, values, *, config, static_px, temperature):
    return tsmrf.ground_weight(prep, tsmrf.make_params(values), config=config, radius_px=static_px,
                               temperature=temperature)


def _pmf_weight(prep, values, *, config, static_px, temperature):
    del static_px                       # the window series is static (config.windows_px)
    return tpmf.ground_weight(prep, tpmf.make_params(values), config=config, temperature=temperature)


SMRF = GradientTuner(
    name="smrf", bounds=tsmrf.BOUNDS, units=tsmrf.UNITS, config_type=smrf_method.Config, static="window_m",
    grid=tsmrf.GRID["window_m"], prepare_tile=tsmrf.prepare_tile.__wrapped__, ground_weight=_smrf_weight,
    static_px=tsmrf.radius_for, default_static=lambda config: smrf_method.Config().window_m,
    prepared_config=lambda config, grid: dataclasses.replace(
        config, window_m=float(max(max(grid), config.window_m))))
PMF = GradientTuner(
    name="pmf", bounds=tpmf.BOUNDS, units=tpmf.UNITS, config_type=pmf_method.Config, static=None, grid=(),
    prepare_tile=tpmf.prepare_tile.__wrapped__, ground_weight=_pmf_weight,
    static_px=lambda config, value: 0, default_static=lambda config: config.max_window_m,
    prepared_config=lambda config, grid: config)


def _csf_weight(prep, values, *, config, static_px, temperature):
    del config
    return tcsf.ground_weight(prep, values[0], static_px, temperature=temperature)


def _csf_values(code: float) -> dict:
    time_step, rigidness = tcsf.decode(code)
    return {"time_step": time_step, "rigidness": rigidness}


CSF = GradientTuner(
    name="csf", bounds=tcsf.BOUNDS, units=tcsf.UNITS, config_type=csf_method.Config, static="cloth",
    grid=tcsf.GRID, prepare_tile=None, ground_weight=_csf_weight,
    static_px=lambda config, value: config.index(value),
    default_static=lambda config: tcsf.encode(float(csf_method.Params().time_step),
                                              getattr(config, "csf", config).rigidness),
    prepared_config=lambda config, grid: tcsf.TuneConfig(config, tuple(sorted({*grid, tcsf.encode(
        float(csf_method.Params().time_step), config.rigidness)}))),
    prepare_samples=tcsf.prepare_samples, static_values=_csf_values,
    static_note="time_step and rigidness act through the cloth simulation, a while loop with a "
                "displacement stopping rule (no reverse-mode gradient; rigidness is a loop count): "
                "grid search over cloths simulated once per sample, never gradient-fitted")
METHODS = {m.name: m for m in (SMRF, PMF, CSF)}


def get(name: str) -> GradientTuner:
    """The tunable method called `name` (ValueError naming the tunable ones otherwise)."""
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(f"{name!r} cannot be tuned; tunable: {', '.join(METHODS)}") from None
