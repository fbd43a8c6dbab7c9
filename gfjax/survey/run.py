"""A survey filtered file by file, each file labelled as a part of one file of the whole survey.

A tiled method runs each tile of the survey's lattice once (`gfjax.survey.lattice`); any other
method filters each file with its neighbours' points within `HALO_M` (`gfjax.survey.halo`), or,
one whose labels depend on the whole cloud, the whole survey at once when it fits in memory.
"""
from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import ModuleType

import numpy as np

from gfjax import adaptive, methods
from gfjax.errors import InputError
from gfjax.io import atomic, stream
from gfjax.io import las as las_io
from gfjax.io.asprs import DEFAULT_RULES, ClassRules
from gfjax.io.cloud import Cloud
from gfjax.method import Method
from gfjax.result import Result
from gfjax.survey import cluster
from gfjax.survey.catalog import Catalog, index
from gfjax.survey.halo import (
    HALO_M,
    Points,
    file_of_survey,
    filter_file,
    fits_whole,
    halo_width,
    survey_labels,
    survey_settings,
)
from gfjax.survey.lattice import Pieces, TileLabels
from gfjax.tiling.tiles import Lattice, Tiling


class Runner:
    """Filters the files of a catalog, one call per file, in any order.

    Args:
      catalog: the survey (`gfjax.survey.index`).
      filter_fn: `filter_fn(points, returns, core=None) -> Result`, the method with its settings
        (`core`: the points whose labels are kept, `gfjax.method.Method.takes_core`).
      lattice: the method's tiling at its cell when it labels tile by tile (`gfjax.methods.lattice`;
        the survey then runs each tile once), else None (each file with its halo).
      folder: the catalog's private folder.
      returns: "all" or "last".
      context: whether each call also gives the ground points around the file (a tiled
        method gathers them apart; a DTM needs them).
      client: a `dask.distributed.Client` (`gfjax.survey.cluster.client`), or None: every
        tile (a tiled method) or file (any other) is sent to its cluster at once, and each
        call waits for the tasks its file needs. `filter_fn` and `lattice` travel to the
        workers (pickled), and the catalog's folder must be one they reach.
      whole: filter the whole survey as one cloud, once, and give each file its part
        (`fits_whole`; a method without `lattice`): exactly one file's labels.
      halo_m: the context each file of a method without `lattice` is filtered with [m]
        (`gfjax.survey.halo.halo_width`).
      pieces: run a method without `lattice` tile by tile on these squares instead, each with
        its halo (`gfjax.survey.lattice.pieces`): out of core, memory follows a piece, not a
        file (labels near a piece's edge close to, not exactly, one file's). None: file by file.
    """

    def __init__(self, catalog: Catalog, filter_fn: Callable, lattice: Lattice | None, folder: str | Path, *,
                 returns: str = "all",
                 context: bool = True, client=None, whole: bool = False, halo_m: float = HALO_M,
                 pieces: Pieces | None = None):
        self.catalog, self.filter_fn, self.lattice, self.returns = catalog, filter_fn, lattice, returns
        self.halo_m = halo_m
        self.context = context
        self.whole = whole and lattice is None and pieces is None
        self.tiles, self.pending, self.submit, self.survey = None, {}, None, None
        self.survey_error: BaseException | None = None        # the whole survey's run failed
        if client is not None:
            self.submit = _submitter(client, catalog, filter_fn)
        grid = lattice if lattice is not None else pieces
        if grid is not None and catalog.frame is not None:
            self.tiles = TileLabels(catalog, filter_fn, grid, folder, returns=returns)
            if client is not None:
                self.tiles.submit(self.submit)
        elif client is not None and self.whole:
            survey = self.submit(survey_labels, returns=returns)
            self.pending = {i: self.submit(file_of_survey, survey, i, context=context)
                            for i in range(len(catalog.entries))}
        elif client is not None:
            self.pending = {i: self.submit(file_labels, lattice, i, returns=returns, halo_m=halo_m)
                            for i in range(len(catalog.entries))}

    def write(self, i: int, target: str | Path, staged: str | Path, **options):
        """File `i` copied, classified, by a task on the cluster once the tasks it needs are
        done (`write_labels`), to `staged`, a temporary beside `target` that the caller named
        (`gfjax.io.atomic.temporary_name`) and commits (`gfjax.io.atomic.commit`) or removes:
        a future of `(n_ground, n_points)`. `options`: `gfjax.io.stream.relabel`'s. Only with
        a client, and instead of `__call__` or `ground` for that file. Paths as the workers
        see them (absolute, on storage they share)."""
        if self.submit is None:
            raise ValueError("Runner.write: only on a cluster (client=...)")
        if self.tiles is None:
            if i not in self.pending:
                raise ValueError(f"Runner.write: file {i}'s labels were already taken")
            needed = [self.pending[i]]
        else:
            keys = sorted(self.tiles.keys[i])
            if any(key not in self.tiles.pending for key in keys):
                raise ValueError(f"Runner.write: a tile of file {i} was already taken")
            needed = [self.tiles.pending[key] for key in keys]
        return self.submit(write_labels, i, Path(target), Path(staged), options, *needed)

    def release(self) -> None:
        """Forget the filtering tasks (after `write` for every file): each tile's labels then
        stay on the cluster only while a write that needs them waits."""
        self.pending.clear()
        if self.tiles is not None:
            self.tiles.pending.clear()

    def ground(self, i: int) -> np.ndarray:
        """File `i`'s labels, bool `(n_i,)` memory-mapped (a tiled method, or any on `pieces`:
        the file is never read whole; `gfjax filter --out-of-core`)."""
        if self.tiles is None:
            raise ValueError("Runner.ground: only a tiled method, or one run on pieces, labels a file without "
                             "reading it")
        return self.tiles.labels(i)

    def __call__(self, i: int, cloud: Cloud) -> tuple[Result, np.ndarray]:
        """File `i` of the catalog, read as `cloud`, filtered.

        Returns:
          `(result, halo_ground_m)`: the `Result` for the file's own points (without
          diagnostics from a tiled method or a survey run as one cloud: they ran in windows of
          the survey, not of the file), and the
          ground points around the file, float64 `(k, 3)` [m] (they give the file's DTM its
          border cells: `gfjax.dtm.build(context_xyz=...)`; none without `context` from a
          tiled method or a survey run as one cloud).
        """
        if self.tiles is None:
            future = self.pending.pop(i, None)
            if future is not None:
                return cluster.result(future, f"{self.catalog.entries[i].path}")
            if self.whole:
                if self.survey_error is not None:                # every file needs that run: no retry
                    raise self.survey_error
                if self.survey is None:
                    try:
                        self.survey = survey_labels(self.catalog, self.filter_fn, returns=self.returns)
                    except Exception as err:
                        self.survey_error = err
                        raise
                return file_of_survey(self.catalog, self.filter_fn, self.survey, i, context=self.context)
            return filter_file(self.catalog, i, cloud, self.filter_fn, self.lattice, returns=self.returns,
                               halo_m=self.halo_m)
        margin_m = HALO_M if self.context else 0.0
        ground = np.array(self.tiles.labels(i, margin_m))
        return Result(ground=ground), self.tiles.near_ground(i, margin_m)


def file_labels(catalog: Catalog, filter_fn: Callable, lattice: Lattice | None, i: int, *,
                returns: str = "all", halo_m: float = HALO_M) -> tuple[Result, np.ndarray]:
    """`filter_file` on file `i` read from its catalog store, not from the file (a Dask task:
    the points are those the file's read gives, in metres)."""
    records = catalog.entries[i].records()
    own = Points.from_records(records, str(catalog.entries[i].path))
    result, halo_ground_m = filter_file(catalog, i, own, filter_fn, lattice, returns=returns, halo_m=halo_m)
    return result._replace(diagnostics=None), halo_ground_m


def write_labels(catalog: Catalog, filter_fn: Callable, i: int, target: Path, staged: Path, options: dict,
                 *results) -> tuple[int, int]:
    """A task: file `i`'s labels gathered from the `results` of the tasks that labelled it
    (`tile_labels`'s parts, or `file_labels`'s `(result, halo)`), and its copy written with
    them (`gfjax.io.stream.relabel`) to `staged`, a temporary beside `target` named by the
    process that commits it. Returns `(n_ground, n_points)`."""
    entry = catalog.entries[i]
    ground = np.zeros(entry.n_points, bool)
    for result in results:
        if isinstance(result, tuple):                 # file_labels: (Result, halo ground)
            ground = np.asarray(result[0].ground, bool)
            continue
        for j, rows, labels in result:
            if j == i:
                ground[rows] = labels
    return stream.relabel(entry.path, target, ground, staged=staged, **options)


def _submitter(client, catalog: Catalog, filter_fn: Callable) -> Callable:
    """`submit(fn, *args) -> future` of `fn(catalog, filter_fn, *args)` on `client`'s cluster,
    the catalog and `filter_fn` sent once, not with every task; tasks are never cached by
    Dask's key (`pure=False`: a rerun of the survey filters again)."""
    catalog_f, filter_f = client.scatter([catalog, filter_fn], broadcast=True, hash=False)

    def submit(fn: Callable, *args, **kwargs):
        return client.submit(fn, catalog_f, filter_f, *args, pure=False, **kwargs)

    return submit


def filtered(paths: Sequence[str | Path], method: Method | ModuleType | str, folder: str | Path, *, config=None, params=None,
             tiling: Tiling | None = None, returns: str = "all", units: str | None = None, client=None,
             classes: ClassRules = DEFAULT_RULES, **options) -> Iterator[tuple[Cloud, Result]]:
    """Each file of a survey and its `Result`, filtered as a part of the whole survey.

    ```python
    for cloud, result in gfjax.survey.filtered(paths, "dmf", tmp_folder):
        ...                                   # result.ground: the file's own points
    ```

    Args:
      paths: the survey's files.
      method: a `gfjax.method.Method`, its package (`gfjax.dmf`) or its name.
      folder: a private temporary folder for the catalog's stores.
      config, params: the method's settings. Without a `config`, the values that follow the data
        are settled once on the whole survey (`survey_settings`; a given `params` is kept whole)
        and the method runs as `gfjax filter` runs it (`adaptive.run`), so the survey labels as
        its files joined into one would be; with one, as given.
      tiling: a tiled method's tiles (`gfjax.Tiling`, None: its defaults); they also set the
        windows each file is filtered with.
      returns: "all" or "last".
      units: `--units` override.
      client: a `dask.distributed.Client` whose cluster filters the tiles (`Runner`), or None
        for this process.
      classes: the classes the filter ignores and those whose class it keeps (`Cloud.classes`).
      options: further keyword arguments of the method's `filter` (SparseGF's `model`).

    Yields:
      `(cloud, result)` per file in the order of `paths`; `result.ground` covers the file's
      own points only.
    """
    method = methods.of(method)
    if tiling is not None:
        if not method.tiles:
            raise InputError(f"tiling: method {method.name} does not tile")
        options = {**options, "tiling": tiling}
    catalog = index(paths, folder, returns=returns, units=units, client=client, classes=classes, keep_points=True)
    fixed = None                    # a config given: nothing settles
    if config is None:
        params, fixed = adaptive.given_params(params, method.Params)
    settings = survey_settings(method, catalog, method.Config() if config is None else config, params, fixed=fixed,
                               returns=returns)
    config, options = settings.config, {**options, **settings.options}
    filter_fn = functools.partial(_method_filter, method, config, settings.params, settings.settled, options)
    run = Runner(catalog, filter_fn, methods.lattice(method, config, tiling), folder, returns=returns, context=False,
                 client=client, whole=fits_whole(method, config, catalog), halo_m=halo_width(method, config))
    for i, entry in enumerate(catalog.entries):
        cloud = las_io.read(entry.path, units=units, classes=classes, stored=entry.points)
        yield cloud, run(i, cloud)[0]


def _method_filter(method: Method, config, params, settled, options: dict, points: Points, returns: str,
                   core: np.ndarray | None = None) -> Result:
    return adaptive.run(method.filter, points, settled, config=config, params=params, returns=returns,
                        hides_low_outliers=method.hides_low_outliers, **options, **method.core_option(core))


def filter(paths: Sequence[str | Path], out: str | Path, *, method: Method | ModuleType | str = methods.DEFAULT_METHOD,
           config=None, params=None, tiling: Tiling | None = None, returns: str = "all", units: str | None = None,
           client=None, classes: ClassRules = DEFAULT_RULES,
           reset_nonground: bool = False, force: bool = False, **options) -> list[Path]:
    """Filter a survey as one and write each file's copy, classified, into the folder `out`.

    ```python
    from dask.distributed import Client
    with Client("tcp://scheduler:8786") as client:
        gfjax.survey.filter(sorted(Path("survey").glob("*.laz")), "classified", method="smrf", client=client)
    ```

    Each output keeps every point and attribute of its input; only the classification changes
    (`Cloud.with_ground`), and it is written atomically, by this process, once every tile of its
    file is done (`gfjax filter --scheduler` has the workers write the copies: `Runner.write`).

    Args:
      paths: the survey's LAS/LAZ files.
      out: an existing folder; each output has its input's name.
      method, config, params, tiling, returns, units, client, classes, options: as `filtered`.
      reset_nonground: every non-ground point becomes class 1 (default: only former class 2).
      force: overwrite existing outputs.

    Returns:
      The paths written, in the order of `paths`.
    """

    out = Path(out)
    if not out.is_dir():
        raise InputError(f"{out}: not an existing folder")
    written = []
    with atomic.scratch_folder() as folder:
        for cloud, result in filtered(paths, method, folder, config=config, params=params, tiling=tiling, returns=returns,
                                      units=units, client=client, classes=classes, **options):
            labelled = cloud.with_ground(result.ground, reset_nonground=reset_nonground,
                                         used=cloud.filter_mask(returns))
            written.append(las_io.write(labelled, out / Path(cloud.path).name, force=force, input_paths=paths))
    return written
