"""`gfjax filter IN... -o OUT`: classify ground points and write LAS/LAZ.

Ground points get class 2; non-ground points that were class 2 become 1, others keep their
class (all become 1 with `--reset-nonground`); noise (7, 18), withheld points and, with
`--returns last`, non-last returns keep their class. Nothing else in the file changes, except
an `instance_id` extra-bytes dimension with `--instances`. With several inputs (or a glob),
OUT is an existing folder and each output has its input's name.

Several inputs are filtered as one survey: every file is read once to index it, then each is
filtered with a halo of its neighbours' points on the survey's tiling, so a point near a
file border gets the label it would get if the survey were one file (exactly so for the
tiled methods, SMRF and PMF, and for CSF, which filters the whole survey at once when it
fits the memory budget). The files must share their CRS and units. `--independent` filters
each file on its own instead.

`--workers N` runs the survey as tasks on a local Dask cluster of N worker processes, which
share this machine's cores: each file's index and each tile (each file with its halo, for a
method that does not tile); this process writes the files. `--scheduler ADDRESS` sends them
to an existing Dask cluster, whose workers must reach the inputs, the outputs and the
temporary folder (`TMPDIR`) at the same paths; there each file's classified copy is a task
too, renamed into place here in the files' order (this process writes the files with `--dtm`
or `--instances`). Outputs, errors and the summary are those of one process; a worker that
dies has its task run again.

A file too large for the memory budget (`GFJAX_MEMORY_BUDGET_GB`, default half the
machine's memory) is filtered out of core, by any method (`--out-of-core` forces it): read
a chunk at a time into an index on disk (28 bytes a point, in a private temporary folder),
filtered one window at a time, and written by copying the input a chunk at a time with
the new classes; memory follows the largest window, not the file. SMRF and PMF run tile
windows, with exactly the labels of the file in memory; any other method runs pieces with the
points within its survey halo around each (50 m; DMF's and SparseGF's their own), a piece and
its halo one 500 m tile (smaller where the densest file's points in one would not fit the
budget), so labels near a piece's edge are close to, not exactly, those of the file in
memory, as near a file's edge in a survey.

Every option, input and output is checked before the first file is filtered (option ranges
and the memory their rasters need, headers, CRS and units, output folders, free space), so a
bad option or path fails at once and leaves no file behind. An existing output file (or an
input given as output) is overwritten only with `--force`. A file that fails later leaves
the outputs already written (each complete), and a summary line says which files were done,
failed or not started (exit 2); `--keep-going` goes on with the other files. With `--dtm`,
a file's DTM and point cloud are both written or neither; `--dtm-mosaic` is written only
when every file was.
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gfjax.cli import _job
from gfjax.cli._common import (
    POINTS_OUTPUT_HELP,
    TIF_SUFFIXES,
    add_method_options,
    add_units_option,
    check_written_forms,
    class_list,
    method_setup,
    nonnegative_float,
    output_targets,
    positive_float,
    say_crs_warning,
    workers_count,
)
from gfjax.errors import InputError
from gfjax.io import atomic
from gfjax.io import las as las_io


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("filter", help="classify ground points, write LAS/LAZ (and a DTM)",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="IN", help="LAS/LAZ files, folders or globs")
    parser.add_argument("-o", "--output", required=True, metavar="OUT",
                        help=POINTS_OUTPUT_HELP)
    add_method_options(parser, method_help="ground filter", default_method=True, tiling=True)
    parser.add_argument("--tile-size", type=positive_float, default=None, metavar="M",
                        help="tile core side [m], for the methods that tile (listed below)")
    parser.add_argument("--buffer", type=nonnegative_float, default=None, metavar="M",
                        help="context around each tile [m], for the methods that tile (listed below)")
    parser.add_argument("--returns", choices=("all", "last"), default="all",
                        help="returns the filter uses (default all)")
    parser.add_argument("--ignore-class", type=class_list, default=(), metavar="LIST",
                        help="classes the filter neither uses nor relabels, e.g. 9,17 (noise 7, 18 and withheld "
                             "points always)")
    parser.add_argument("--keep-class", type=class_list, default=(), metavar="LIST",
                        help="classes the filter uses as context but never relabels, e.g. 6,9,17")
    parser.add_argument("--reset-nonground", action="store_true",
                        help="set every non-ground point to class 1 (default: only former class 2)")
    parser.add_argument("--instances", action="store_true",
                        help="add a uint32 extra-bytes dimension instance_id (methods that give one)")
    parser.add_argument("--dtm", default=None, metavar="DTM.tif",
                        help="also write a DTM GeoTIFF from the ground points (a folder for several inputs)")
    parser.add_argument("--hillshade", action="store_true",
                        help="with --dtm: also write each DTM's hillshade beside it (DTM.png)")
    parser.add_argument("--dtm-mosaic", default=None, metavar="MOSAIC.tif|.vrt",
                        help="with --dtm and several inputs: also join their DTMs into one GeoTIFF, or a "
                             "GDAL virtual mosaic (.vrt: the DTMs stay where they are), written once every "
                             "file is done")
    parser.add_argument("--cell", type=positive_float, default=1.0, metavar="M",
                        help="DTM cell size [m] (default 1)")
    parser.add_argument("--independent", action="store_true",
                        help="filter each input on its own, without its neighbours' points")
    parser.add_argument("--workers", type=workers_count, default=None, metavar="N",
                        help="filter the tiles as tasks on a local Dask cluster of N worker processes, or "
                             "'auto': one a core; fewer, or none, for a survey too small to gain "
                             "(needs dask.distributed: pip install 'gfjax[dask]')")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="filter the tiles on the Dask cluster at ADDRESS (tcp://host:8786); its workers "
                             "must reach the inputs and the temporary folder (TMPDIR)")
    parser.add_argument("--out-of-core", action="store_true",
                        help="filter from disk, memory bounded by a tile's window (SMRF, PMF) or a piece and its "
                             "halo (any other method); chosen by itself for a file larger than the memory budget")
    add_units_option(parser)
    parser.add_argument("--trust-data", action="store_true",
                        help="when a header's point count disagrees with the points the file holds, "
                             "filter the points present (and say so) instead of stopping")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="say on stderr the values chosen from the data (cell sizes, thresholds), "
                             "the terrain statistics they follow from, and on a survey the values fixed once "
                             "for every file")
    parser.add_argument("--force", action="store_true",
                        help="overwrite existing output files, and input files given as outputs")
    parser.add_argument("--keep-going", action="store_true",
                        help="with several inputs, go on with the other files after one fails (exit 2 at the end)")
    return parser


def run(args: argparse.Namespace) -> int:
    from gfjax.io.asprs import ClassRules

    args.classes = ClassRules(frozenset(args.ignore_class), frozenset(args.keep_class))
    inputs = las_io.expand_inputs(args.inputs)
    targets = output_targets(inputs, args.output, suffixes=las_io.LAS_SUFFIXES)
    dtm_targets = [None] * len(inputs)
    if args.dtm is not None:
        dtm_targets = output_targets(inputs, args.dtm, option="--dtm", suffixes=TIF_SUFFIXES,
                                     rename_suffix=".tif")
    if args.dtm_mosaic is not None and args.dtm is None:
        raise InputError(f"--dtm-mosaic {args.dtm_mosaic}: needs --dtm (the per-file DTMs it joins)")
    if args.hillshade and args.dtm is None:
        raise InputError("--hillshade: needs --dtm (the DTMs it shades)")
    shades = [hillshade_target(t) for t in dtm_targets if t is not None and args.hillshade]
    # Every output before any file is read: none may exist (or be an input) without --force.
    _job.check_outputs([*(("-o", t, las_io.LAS_SUFFIXES) for t in targets),
                        *(("--dtm", t, TIF_SUFFIXES) for t in dtm_targets if t is not None),
                        *(("--hillshade", t, (".png",)) for t in shades),
                        *((("--dtm-mosaic", args.dtm_mosaic, (*TIF_SUFFIXES, ".vrt")),) if args.dtm_mosaic else ())],
                       inputs=inputs, force=args.force)
    if args.dtm_mosaic is not None and Path(args.dtm_mosaic).resolve() in set(map(Path.resolve, dtm_targets)):
        raise InputError(f"--dtm-mosaic {args.dtm_mosaic}: same path as a file's DTM")
    if args.dtm is not None:
        if set(map(Path.resolve, dtm_targets)) & set(map(Path.resolve, targets)):
            raise InputError(f"--dtm {args.dtm}: same path as an output point cloud")
        from gfjax import dtm as dtm_lib  # imported before any filtering: fail early if absent

        dtm_lib.check_options("", cell_m=args.cell)
    # Options before files: every value in range, the rasters they set within the memory budget.
    setup = method_setup(args, tiling=(args.tile_size, args.buffer))
    # Every input and output before the first file is filtered.
    planned = _job.precheck(inputs, targets, dtm_targets, units=args.units, estimates=setup.memory_estimates,
                            dtm_cell_m=args.cell if args.dtm else None,
                            extra_bytes_per_point=4 if args.instances else 0, trust_data=args.trust_data)
    say_crs_warning([(job.source, job.crs_units) for job in planned])
    check_written_forms([(job.source, job.header, job.target) for job in planned])
    out_of_core = _out_of_core(args, setup, planned)
    if out_of_core is not None:
        setup = out_of_core
    # cleanup errors ignored: after a failed task a worker may still be writing a store there
    with atomic.scratch_folder() as folder, \
            _cluster(args, sum(job.header.point_count for job in planned)) as client:
        if args.scheduler is not None and args.dtm is None and not args.instances:
            return _run_on_cluster(args, setup, inputs, planned, folder, client)
        if out_of_core is not None:
            return _run_out_of_core(args, setup, inputs, planned, folder, client)
        runner = None
        if client is not None or (len(inputs) > 1 and not args.independent):
            from gfjax import survey

            catalog = survey.index(inputs, folder, returns=args.returns, units=args.units,
                                   trust_data=args.trust_data, client=client, classes=args.classes,
                                   keep_points=True)
            setup = _survey_setup(setup, catalog, args)
            runner = survey.Runner(catalog, functools.partial(_filter, setup, client is None), setup.lattice, folder,
                                   returns=args.returns, context=args.dtm is not None, client=client,
                                   whole=_whole(setup, catalog), halo_m=survey.halo_width(setup.method, setup.config))
        return _run(args, setup, inputs, planned, runner)


def _run_on_cluster(args, setup, inputs, planned, folder, client) -> int:
    """Filter and write every planned file on a cluster of other machines (`--scheduler`): the
    tiles (or files) as tasks, then each file's copy, classified, written to a temporary by a
    task once its labels are done (`gfjax.survey.Runner.write`), so the classified copies are not
    written through this machine; here each is committed in the files' order, so a file that fails
    leaves the later ones unwritten, as in one process. (A local cluster's files are written
    here, where they are: this process's writer then uses the cores the workers leave idle.)
    This process still reads the stores once, for the tiles each file meets."""
    from gfjax import survey
    from gfjax.survey import cluster

    catalog = survey.index(inputs, folder, returns=args.returns, units=args.units, trust_data=args.trust_data,
                           client=client, classes=args.classes)
    setup = _survey_setup(setup, catalog, args)
    runner = survey.Runner(catalog, functools.partial(_filter, setup, False), setup.lattice, folder,
                           returns=args.returns, context=False, client=client, whole=_whole(setup, catalog),
                           halo_m=survey.halo_width(setup.method, setup.config))
    position = {source: i for i, source in enumerate(inputs)}
    # temporaries named here: this process's id in their names keeps other sweeps off them
    # (absolute paths: workers resolve a relative one in their own working folder)
    staged = {job.source: atomic.temporary_name(job.target.absolute()) for job in planned}
    writes = {job.source: runner.write(position[job.source], job.target.absolute(), staged[job.source],
                                       returns=args.returns, reset_nonground=args.reset_nonground, force=args.force,
                                       input_paths=[p.absolute() for p in inputs], trust_data=args.trust_data,
                                       classes=args.classes)
              for job in planned}
    runner.release()
    committed: set[Path] = set()

    def one(job: _job.Planned) -> None:
        start = time.perf_counter()
        n_ground, n = cluster.result(writes[job.source], str(job.source))
        if n != job.header.point_count:
            print(f"gfjax: warning: {job.source}: header says {job.header.point_count:,} points, the file holds "
                  f"{n:,}; filtered the {n:,} points present (--trust-data)", file=sys.stderr)
        atomic.commit(staged[job.source], job.target, exclusive=not args.force)
        committed.add(job.source)
        seconds = time.perf_counter() - start
        print(f"{job.source} -> {job.target}: {setup.name} (on the cluster), {n_ground:,} ground of {n:,} points "
              f"({100.0 * n_ground / max(n, 1):.1f} %), waited {seconds:.1f} s")

    try:
        return _job.run_files(planned, one, keep_going=args.keep_going, report=None)
    finally:
        # the copies not committed: cancelled, and removed if written; one still being written
        # when this process ends carries its id, so the next run's sweep of the folder removes it
        for source, future in writes.items():
            if source not in committed:
                future.cancel()
                Path(staged[source]).unlink(missing_ok=True)


def _whole(setup, catalog) -> bool:
    """Whether the survey runs as one cloud (`gfjax.survey.fits_whole`); when the method's labels
    depend on the whole cloud but the survey does not fit, one line on stderr says so."""
    from gfjax import survey

    if survey.fits_whole(setup.method, setup.config, catalog):
        return True
    if setup.method.whole_cloud and catalog.frame is not None:
        print(f"gfjax: warning: {setup.name}: the survey does not fit the memory budget as one cloud; each file "
              f"is filtered with {survey.HALO_M:g} m of its neighbours' points, so labels near file borders may "
              "differ from those of one file", file=sys.stderr)
    return False


def _survey_setup(setup, catalog, args, whole: bool | None = None):
    """`setup` for a survey (or one file read from disk) with the values its files share
    (`gfjax.survey.survey_settings`; `whole`: whether it runs as one cloud, None: as
    `gfjax.survey.fits_whole` says), said with `-v`."""
    from gfjax import survey

    settings = survey.survey_settings(setup.method, catalog, setup.config, setup.params, fixed=setup.fixed,
                                      returns=args.returns, whole=whole)
    what = str(catalog.entries[0].path) if len(catalog.entries) == 1 else "the survey"
    if settings.settled is not None:
        setup = setup.fixed_at(settings.settled)
        _say_settled(args, what, settings.settled)
    elif settings.terrain is not None and getattr(args, "verbose", False):
        print(f"gfjax: {what}: terrain: {settings.terrain.describe()}", file=sys.stderr)
    if settings.estimated and getattr(args, "verbose", False):
        from gfjax import adaptive

        print(f"gfjax: {what}: estimated once on all of it: {adaptive.show(settings.estimated)}", file=sys.stderr)
    return setup._replace(config=settings.config, options={**(setup.options or {}), **settings.options})


def _say_settled(args, what: str, settled) -> None:
    """With `-v`, the values chosen from the data and the terrain they came from, on stderr."""
    if getattr(args, "verbose", False) and settled is not None:
        text = settled.describe().replace("\n", "\n  ")
        print(f"gfjax: {what}: {text}", file=sys.stderr)


def _filter(setup, progress: bool, points, returns: str, core=None):
    """`setup`'s filter on a survey's window, `core` the points whose labels are kept (a
    module-level function: it travels to Dask workers)."""
    return setup.filter(points, returns=returns, progress=progress, **setup.method.core_option(core))


def _cluster(args: argparse.Namespace, points: int):
    """The Dask client that `--workers` / `--scheduler` ask for (`gfjax.survey.cluster`), or
    a context giving None; a local cluster only as large as the survey's `points` pay for
    (`cluster.local_workers`, which says so when that is not what was asked)."""
    if args.workers is None and args.scheduler is None:
        return contextlib.nullcontext(None)
    if args.workers is not None and args.scheduler is not None:
        raise InputError("--workers and --scheduler: give one (a local cluster of N workers, or an existing one)")
    if args.independent:
        option = "--workers" if args.workers is not None else "--scheduler"
        raise InputError(f"{option}: the cluster filters the inputs as one survey; drop --independent")
    from gfjax.survey import cluster

    workers = None
    if args.workers is not None:
        workers, note = cluster.local_workers(args.workers, points)
        if note is not None:
            print(f"gfjax: {note}", file=sys.stderr)
        if workers == 0:
            return contextlib.nullcontext(None)
    return cluster.client(workers=workers, scheduler=args.scheduler)


def _run(args, setup, inputs, planned, runner) -> int:
    """Filter and write every planned file (as a part of the survey when `runner` is set:
    `gfjax.survey.Runner`)."""
    say, report, progress = print, None, None
    if len(inputs) > 1:                     # a progress bar over files (tqdm: 40 ms to import)
        from tqdm.auto import tqdm

        progress, say = tqdm(total=len(inputs), desc="files", unit="file"), tqdm.write

        def report(line: str) -> None:
            tqdm.write(line, file=sys.stderr)

    position = {source: i for i, source in enumerate(inputs)}

    def one(job: _job.Planned) -> None:
        start = time.perf_counter()
        # a survey's file as its catalog kept it: not decompressed a second time
        stored = None if runner is None else runner.catalog.entries[position[job.source]].points
        cloud = las_io.read(job.source, units=args.units, trust_data=args.trust_data, classes=args.classes,
                            stored=stored)
        if cloud.n_points != job.header.point_count:
            print(f"gfjax: warning: {job.source}: header says {job.header.point_count:,} points, the file holds "
                  f"{cloud.n_points:,}; filtering the {cloud.n_points:,} points present (--trust-data)",
                  file=sys.stderr)
        halo_ground_m = None
        if runner is None:
            result = setup.filter(cloud, returns=args.returns, progress=True)
            _say_settled(args, str(job.source), result.settled)
            for note in result.notes:
                print(f"gfjax: {job.source}: {note}", file=sys.stderr)
        else:
            result, halo_ground_m = runner(position[job.source], cloud)
        # points of a kept class keep their class: not ground in the file, the counts or the DTM
        ground = np.asarray(result.ground, dtype=bool) & ~cloud.classes.kept(cloud.classification)
        labelled = cloud.with_ground(ground, reset_nonground=args.reset_nonground,
                                     used=cloud.filter_mask(args.returns))
        if args.instances:
            if result.instance_id is None:
                raise InputError(f"--instances: method {setup.name} gives no instance ids")
            labelled = labelled.with_extra_dim("instance_id", np.asarray(result.instance_id, dtype=np.uint32),
                                               description="object instance, 0 = none")
        _write(labelled, job.target, job.dtm_target, cloud, ground, args, inputs, halo_ground_m)
        seconds = time.perf_counter() - start
        n_ground = int(np.count_nonzero(ground))
        say(f"{job.source} -> {job.target}: {setup.name}, {n_ground:,} ground of {cloud.n_points:,} points "
            f"({100.0 * n_ground / cloud.n_points:.1f} %), {seconds:.1f} s "
            f"({cloud.n_points / max(seconds, 1e-9):,.0f} points/s)")
        if progress is not None:
            progress.update(1)

    try:
        code = _job.run_files(planned, one, keep_going=args.keep_going, report=report)
    finally:
        if progress is not None:
            progress.close()
    if args.dtm_mosaic is not None:
        if code != 0:
            print(f"gfjax: --dtm-mosaic {args.dtm_mosaic}: not written, not every file was filtered", file=sys.stderr)
        else:
            from gfjax import dtm as dtm_lib

            h, w = dtm_lib.mosaic([job.dtm_target for job in planned], args.dtm_mosaic)
            print(f"DTM mosaic of {len(planned)} files -> {args.dtm_mosaic} ({h:,} x {w:,} cells)")
    return code


def _out_of_core(args, setup, planned):
    """The setup to filter with from disk, or None to filter in memory. Out of core:
    `--out-of-core`, or a file whose points, filtered in memory, would take more than the memory
    budget (`limits.IN_MEMORY_BYTES_PER_POINT`): a tiled method a tile window at a time, any
    other a piece and its halo at a time (`gfjax.survey.lattice.Pieces`)."""
    from gfjax import limits
    budget = limits.memory_budget_bytes()
    need = [(job, job.header.point_count * (job.header.point_format.size + limits.IN_MEMORY_BYTES_PER_POINT))
            for job in planned]
    large = [(job, size) for job, size in need if size > budget]
    if not (args.out_of_core or large):
        return None
    why = "--out-of-core" if args.out_of_core else (
        f"{large[0][0].source}: {large[0][0].header.point_count:,} points need about {large[0][1] / 2**30:.1f} "
        f"GiB filtered in memory, more than the budget of {budget / 2**30:.1f} GiB (set {limits.BUDGET_ENV} to "
        "change it)")
    from gfjax.io import copc_writer

    copcs = [job.target for job in planned if copc_writer.is_copc_name(job.target)]
    for option, given in (("--dtm", args.dtm is not None), ("--instances", args.instances),
                          (f"-o {copcs[0] if copcs else ''} (COPC, an octree over every point)", bool(copcs))):
        if given:
            raise InputError(f"{why}: {option} needs the file in memory; filter without it out of core")
    if not args.out_of_core:
        how = "a tile at a time" if setup.lattice is not None else \
            "a piece and its halo at a time (labels near a piece's edge may differ from the file's in memory)"
        print(f"gfjax: {why}: filtering out of core with {setup.name}, {how}", file=sys.stderr)
    return setup


def _run_out_of_core(args, setup, inputs, planned, folder, client=None) -> int:
    """Filter and write every planned file tile by tile from disk (`gfjax.survey.lattice`): the
    files as one survey, or each alone with `--independent`."""
    from gfjax import survey
    from gfjax.io import stream

    shared = None
    if client is not None or (len(inputs) > 1 and not args.independent):
        catalog = survey.index(inputs, folder, returns=args.returns, units=args.units, trust_data=args.trust_data,
                               client=client, classes=args.classes)
        shared = (_disk_runner(setup, catalog, folder, args, client), {source: i for i, source in enumerate(inputs)})

    def one(job: _job.Planned) -> None:
        if shared is not None:
            return write(job, shared[0], shared[1][job.source])
        with tempfile.TemporaryDirectory(prefix="file-", dir=folder) as own:      # this file's index only
            catalog = survey.index([job.source], own, returns=args.returns, units=args.units,
                                   trust_data=args.trust_data, classes=args.classes)
            write(job, _disk_runner(setup, catalog, own, args), 0)

    def write(job: _job.Planned, runner, i: int) -> None:
        start_s = time.perf_counter()
        n_ground, n = stream.relabel(job.source, job.target, runner.ground(i), returns=args.returns,
                                     reset_nonground=args.reset_nonground, force=args.force, input_paths=inputs,
                                     trust_data=args.trust_data, classes=args.classes, exclusive=not args.force)
        seconds = time.perf_counter() - start_s
        print(f"{job.source} -> {job.target}: {setup.name} (out of core), {n_ground:,} ground of {n:,} "
              f"points ({100.0 * n_ground / max(n, 1):.1f} %), {seconds:.1f} s ({n / max(seconds, 1e-9):,.0f} points/s)")

    return _job.run_files(planned, one, keep_going=args.keep_going, report=None)


def _disk_runner(setup, catalog, folder, args, client=None):
    """The `gfjax.survey.Runner` that labels `catalog`'s files from disk (`Runner.ground`): a
    tiled method tile by tile, any other on `gfjax.survey.lattice.pieces`, each with its halo."""
    from gfjax import survey
    from gfjax.survey import lattice
    from gfjax.tiling.tiles import Tiling

    settled = _survey_setup(setup, catalog, args, whole=False)
    halo_m = survey.halo_width(settled.method, settled.config)
    pieces = None
    if settled.lattice is None:
        pieces = lattice.pieces(catalog, halo_m, (settled.tiling or Tiling()).tile_size_m)
    return survey.Runner(catalog, functools.partial(_filter, settled, False), settled.lattice, folder,
                         returns=args.returns, context=False, client=client, halo_m=halo_m, pieces=pieces)


def _write(labelled, target: Path, dtm_target: Path | None, cloud, ground: np.ndarray,
           args: argparse.Namespace, inputs, halo_ground_m: np.ndarray | None = None) -> None:
    """Write the classified cloud, and its DTM with `--dtm` (and the DTM's hillshade with
    `--hillshade`): all or none.

    In a survey the DTM also takes the ground points of the file's halo (`halo_ground_m`,
    metres), so adjacent files' DTMs give their shared border cells the same values.

    The DTM is built before anything is written (no ground points, a grid over the memory
    budget: nothing written), then written while the cloud's temporary file waits to be
    renamed; if the cloud then fails, the rasters this call wrote are removed again, and those
    that were there before (`--force`) are put back, so the old set stays a set.
    """
    if dtm_target is None:
        las_io.write(labelled, target, force=args.force, input_paths=inputs, exclusive=not args.force)
        return
    from gfjax import dtm as dtm_lib

    context = None
    if halo_ground_m is not None:
        context = halo_ground_m / np.array([cloud.horizontal_unit_m, cloud.horizontal_unit_m, cloud.vertical_unit_m])
    dtm = dtm_lib.build(cloud, ground, cell_m=args.cell, context_xyz=context)
    kept: list[Path] = []          # the earlier DTM, moved aside until the cloud is in place
    written = []

    rasters = [(dtm_target, dtm.to_geotiff)]
    if args.hillshade:
        rasters.append((hillshade_target(dtm_target), dtm.to_png))

    def write_dtm() -> None:
        for path, write in rasters:
            if path.exists():
                backup = atomic.temporary_name(path)
                os.replace(path, backup)
                kept.append((backup, path))
            write(path)
            written.append(path)

    try:
        las_io.write(labelled, target, force=args.force, input_paths=inputs, before_commit=write_dtm,
                     exclusive=not args.force)
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        for backup, path in kept:
            os.replace(backup, path)
        raise
    for backup, _ in kept:
        backup.unlink(missing_ok=True)


def hillshade_target(dtm_target: Path) -> Path:
    """Where `--hillshade` writes a DTM's hillshade: beside it, `.png` for `.tif`."""
    return Path(dtm_target).with_suffix(".png")
