"""`Method`: everything the rest of gfjax knows of one ground filter, as one typed value.

Each method package exports its value as `METHOD` (`gfjax.smrf.METHOD`, ...), and
`gfjax.methods` lists the packages. The CLI, surveys, warm-up, tuning and the option table
read these fields and nothing else of a package, so a new method is its own package and one
line of `gfjax.methods.PACKAGES`.

```python
m = gfjax.methods.get("smrf")
config, params = m.Config(window_m=12.0), m.Params(slope=0.2)
result = m.filter(cloud, config=config, params=params)
```
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

from gfjax.limits import Range

TUNINGS = ("gradient", "grid")     # how `gfjax tune` fits a method: optax on relaxed labels, or a grid search


@dataclasses.dataclass(frozen=True, eq=False)
class Method:
    """One ground filter.

    Attributes:
      name: the `--method` name.
      filter: `filter(cloud, *, config=None, params=None, returns="all", progress=False,
        **options) -> gfjax.Result`; the options are `tiling` (when `tiles`) and `model`
        (when it has `load_model`).
      Config: frozen dataclass of static values (shapes, loop counts, cell sizes) [m]; where
        they set rasters or loops, `memory_estimates(extent_m=None[, tiling=None])` gives the
        largest allocations they imply (`gfjax.methods.memory_estimates`).
      Params: `gfjax.params.Params` subclass of traced thresholds optax may tune [m], or None.
      presets: preset name -> `{key: value}` overrides (`--preset`).
      ranges: `--set` key -> its valid `gfjax.limits.Range` (the fields of Config and Params).
      adapt: `adapt(terrain) -> {key: value}`, the values that follow the cloud
        (`gfjax.adaptive`), or None.
      hides_low_outliers: a run whose values follow the cloud hides its low outliers from the
        method first (`gfjax.low_outliers`, `gfjax.adaptive.run`); each package says why in its
        `config.HIDES_LOW_OUTLIERS`.
      warm: `warm(config=None, params=None, *, progress=False) -> int`: load or compile the
        programs `filter` runs for every canonical input shape (`gfjax warmup`), or None.
      tiles: `filter` cuts its work into buffered tiles and takes `tiling=gfjax.Tiling(...)`.
      tile_labels: a tile's core labels depend on its window only, so a survey runs each tile
        of its lattice once (`gfjax.methods.lattice`).
      whole_cloud: a point's label depends on the whole cloud (CSF's cloth settles over all
        of it): a survey that fits the memory budget is filtered as one cloud.
      takes_terrain: `filter` takes `terrain=` (a `gfjax.adaptive.Terrain`), the terrain its values
        settle on in place of the cloud's own (the vote's voters): a survey passes its own, so
        every window is labelled with the values of the whole survey.
      takes_core: `filter` takes `core=` (bool `(n,)`, the points whose labels the caller
        keeps: a survey window's core, a file beside its halo) and spends less on the rest,
        which only give context (`core_option`).
      survey_config: `survey_config(config, clouds, frame) -> Config`, the estimates made per
        cloud fixed once for a whole survey run in windows (DMF's voxel size, CSF's cloth start),
        from each file's points (`clouds`, float64 `(n_i, 3)` [m]) on the survey's `frame`, or None.
      survey_halo: `survey_halo(config) -> float`, the context [m] a survey gives each file of
        a method that labels neither tile by tile nor as one cloud (from the survey's config:
        DMF's is a multiple of its voxel size, SparseGF's its patches' outer radius), or None
        for `gfjax.survey.HALO_M`.
      load_model: `load_model(path or None) -> (model, Config it was trained with)` for a
        method whose `filter` takes `model=` (a model file; None: the one shipped; SparseGF),
        else None. A bad file raises `InputError` here, before any output is written.
      tuning: how `gfjax tune` fits it (`TUNINGS`: "gradient" or "grid"), or None when it
        cannot be tuned; its package's `tuning` module holds the `TUNER` (a
        `gfjax.tune.tuners.GradientTuner` or a `gfjax.tune.search.GridTuner`).
    """

    name: str
    filter: Callable[..., Any]
    Config: type
    Params: type | None
    presets: Mapping[str, Mapping[str, Any]]
    ranges: Mapping[str, Range]
    adapt: Callable[[Any], dict] | None = None
    hides_low_outliers: bool = False
    warm: Callable[..., int] | None = None
    tiles: bool = False
    tile_labels: bool = False
    whole_cloud: bool = False
    takes_terrain: bool = False
    takes_core: bool = False
    survey_config: Callable[..., Any] | None = None
    survey_halo: Callable[[Any], float] | None = None
    load_model: Callable[[Any], tuple[Any, Any]] | None = None
    tuning: str | None = None

    def __post_init__(self):
        if self.tuning is not None and self.tuning not in TUNINGS:
            raise ValueError(f"Method {self.name}: tuning must be one of {TUNINGS} or None, got {self.tuning!r}")
        if self.tile_labels and not self.tiles:
            raise ValueError(f"Method {self.name}: tile_labels needs tiles")
        unknown = set(self.ranges) - _fields(self.Config) - _fields(self.Params)
        if unknown:
            raise ValueError(f"Method {self.name}: ranges of keys that are no field: {sorted(unknown)}")

    def core_option(self, core) -> dict:
        """The keyword arguments that give `filter` the core `core` (bool `(n,)` or None): none
        for a method that does not take one."""
        return {"core": core} if self.takes_core and core is not None else {}

    def __repr__(self) -> str:
        return f"Method({self.name!r})"


def _fields(cls: type | None) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)} if cls is not None else set()
