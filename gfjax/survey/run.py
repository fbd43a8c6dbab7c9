"""A survey filtered file by file, each file labelled as a part of one file of the whole survey.

A tiled method runs each tile of the survey's lattice once (`gfjax.survey.lattice`); any other
method filters each file with its neighbours' points within `HALO_M` (`gfjax.survey.halo`).
"""
from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import ModuleType

import numpy as np

from gfjax import methods
from gfjax.io import las as las_io
from gfjax.io.cloud import Cloud
from gfjax.result import Result
from gfjax.survey.catalog import Catalog, index
from gfjax.survey.halo import HALO_M, Points, filter_file, is_tiled, survey_config
from gfjax.survey.lattice import TileLabels


class Runner:
    """Filters the files of a catalog, one call per file, in any order.

    Args:
      catalog: the survey (`gfjax.survey.index`).
      filter_fn: `filter_fn(points, returns) -> Result`, the method with its settings.
      config: the method's config (its tiling, if any, chooses the path).
      folder: the catalog's private folder.
      returns: "all" or "last".
      context: whether each call also gives the ground points around the file (a tiled
        method gathers them apart; a DTM needs them).
    """

    def __init__(self, catalog: Catalog, filter_fn: Callable, config, folder: str | Path, *, returns: str = "all",
                 context: bool = True):
        self.catalog, self.filter_fn, self.config, self.returns = catalog, filter_fn, config, returns
        self.context = context
        self.tiles = None
        if is_tiled(config) and catalog.frame is not None:
            self.tiles = TileLabels(catalog, filter_fn, config, folder, returns=returns)

    def ground(self, i: int) -> np.ndarray:
        """File `i`'s labels, bool `(n_i,)` memory-mapped (a tiled method only: the file is
        never read whole; `gfjax filter --out-of-core`)."""
        if self.tiles is None:
            raise ValueError("Runner.ground: only a tiled method labels a file without reading it")
        return self.tiles.labels(i)

    def __call__(self, i: int, cloud: Cloud) -> tuple[Result, np.ndarray]:
        """File `i` of the catalog, read as `cloud`, filtered.

        Returns:
          `(result, halo_ground_m)`: the `Result` for the file's own points (a tiled method's
          has no diagnostics: its tiles ran in windows of the survey, not of the file), and the
          ground points around the file, float64 `(k, 3)` [m] (they give the file's DTM its
          border cells: `gfjax.dtm.build(context_xyz=...)`; none from a tiled method
          without `context`).
        """
        if self.tiles is None:
            return filter_file(self.catalog, i, cloud, self.filter_fn, self.config, returns=self.returns)
        margin_m = HALO_M if self.context else 0.0
        ground = np.array(self.tiles.labels(i, margin_m))
        return Result(ground=ground), self.tiles.near_ground(i, margin_m)


def filtered(paths: Sequence[str | Path], method: str | ModuleType, folder: str | Path, *, config=None, params=None,
             returns: str = "all", units: str | None = None, **options) -> Iterator[tuple[Cloud, Result]]:
    """Each file of a survey and its `Result`, filtered as a part of the whole survey.

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

    run = Runner(catalog, filter_fn, config, folder, returns=returns, context=False)
    for i, entry in enumerate(catalog.entries):
        cloud = las_io.read(entry.path, units=units)
        yield cloud, run(i, cloud)[0]
