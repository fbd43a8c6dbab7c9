"""What the tuning loop needs to know of a method, behind one protocol: a `GradientTuner`
(SMRF, PMF, CSF: bounds, a parameter-free preparation, a relaxed ground weight, a static grid
parameter; SPEC section 7) or a `gfjax.tune.search.GridTuner` (MASF, DMF: every combination of
a grid). Each method keeps its own in its package, `gfjax.<method>.tuning.TUNER`; `get` finds it
through the registry (`Method.tuning` says which kind, `gfjax.methods.PACKAGES` where).

A `GradientTuner` is a static argument of the jitted losses (hashed by identity: use the
method's `TUNER`). The values vector `(p,)` is ordered as `GradientTuner.bounds`.
"""
from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from gfjax.tune.params import Bound

__all__ = ["GradientTuner", "get", "of_config"]


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
      grid_keys: the keys a user sets the static grid with (`gfjax.tune.tune(grid=...)`): SMRF
        `window_m`; CSF `time_step` and `rigidness`; none for PMF.
      from_keys: None (the grid is the values given for `static`), or `({key: values}) ->
        static grid` where several keys make one static value (CSF: a cloth per time step and
        rigidness, the defaults for a key not given).
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
    grid_keys: tuple[str, ...] = ()
    from_keys: Callable | None = None

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

    def static_grid(self, requested: Mapping[str, Sequence[float]]) -> tuple[float, ...] | None:
        """The static grid a user's `{key: values}` (keys of `grid_keys`) asks for; None: the default."""
        if self.from_keys is not None:
            return tuple(self.from_keys(requested))
        values = requested.get(self.static) if self.static else None
        return tuple(values) if values else None

    def params_values(self, value: float) -> dict:
        """The params.json entries of a static grid value."""
        return self.static_values(value) if self.static_values else {self.static: float(value)}


def get(name: str) -> Any:
    """The tuner of the method called `name` (`gfjax.<method>.tuning.TUNER`: a `GradientTuner`
    or a `gfjax.tune.search.GridTuner`); ValueError naming the tunable methods otherwise."""
    from gfjax import methods

    tunable = [m for m in methods.names() if methods.get(m).tuning is not None]
    if name not in tunable:
        raise ValueError(f"{name!r} cannot be tuned; tunable: {', '.join(tunable)}")
    return importlib.import_module(f"{methods.PACKAGES[name]}.tuning").TUNER


def of_config(config) -> GradientTuner:
    """The gradient tuner of the method whose `Config` `config` is (ValueError otherwise)."""
    from gfjax import methods

    for name in methods.names():
        found = methods.get(name)
        if found.tuning == "gradient" and isinstance(config, found.Config):
            return get(name)
    raise ValueError(f"config: no method tuned by gradient has a {type(config).__name__}")
