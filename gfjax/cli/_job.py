"""A job over several files: everything checked before the first file, then one file at a time
with a summary of what was done when a file fails (`gfjax filter`).

Before anything is read, `check_outputs` checks every output path: writable, not an input,
and not an existing file unless `--force` (the rule of every command that writes files).
Before the first file is filtered, `precheck` reads every input's header (readable, has
points, CRS and units readable), checks the memory the method's and the DTM's rasters would
need over the file's extent (`gfjax.limits`), and estimates the space the outputs need
against the free space of their folders (`shutil.disk_usage`). `run_files` then runs the
files in order: a file that fails with bad input leaves the outputs already completed (each
is correct and complete: writes are atomic) and ends the job with a summary line and exit 2;
with `keep_going` the other files still run, and the job still exits 2 (1 when a failure was
an internal error) at the end.
"""
from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from gfjax import limits
from gfjax.errors import InputError
from gfjax.io import las as las_io
from gfjax.io.atomic import check_output, existing_output_message
from gfjax.limits import byte_size

_LAZ_OF_LAS = 0.25          # a LAZ written from LAS points: at most about a quarter of the LAS size
_LAZ_SLACK = 1.05           # a LAZ rewritten from a LAZ: about its input size (new classes compress alike)


class Planned(NamedTuple):
    """One input of a job, checked: its path, header, extent [m] and output paths; its CRS and
    units (`gfjax.io.las.CRSUnits`)."""

    source: Path
    header: Any
    extent_m: tuple[float, float]
    target: Path
    dtm_target: Path | None
    crs_units: Any


def _extent_m(header, horizontal_m: float) -> tuple[float, float]:
    mins, maxs = header.mins, header.maxs
    return (float(maxs[0] - mins[0]) * horizontal_m, float(maxs[1] - mins[1]) * horizontal_m)


def output_bytes(header, source: Path, target: Path, *, extra_bytes_per_point: int = 0) -> float:
    """Estimated size of the LAS/LAZ written for `source` [bytes]."""
    n = int(header.point_count)
    las_size = int(header.offset_to_point_data) + n * (int(header.point_format.size) + extra_bytes_per_point)
    if target.suffix.lower() != ".laz":
        return float(las_size)
    if header.are_points_compressed:
        return source.stat().st_size * _LAZ_SLACK + n * extra_bytes_per_point
    return las_size * _LAZ_OF_LAS


def check_outputs(outputs: Sequence[tuple[str, str | os.PathLike, tuple[str, ...] | None]], *,
                  inputs: Sequence[Path] = (), force: bool = False) -> None:
    """Check every output of a command before anything is read or written.

    Args:
      outputs: `(option, path, suffixes)` of each file the command writes, e.g.
        `("-o", "out.laz", (".las", ".laz"))`.
      inputs: the command's input files: an output may be one only with `force`.
      force: `--force`: existing outputs (and inputs) are overwritten.

    Raises:
      InputError: an output that cannot be written (`gfjax.io.atomic.check_output`), or, without
        `force`, one that is an input or that exists: the first is named, with the count of
        the others, so a run over many files is refused before its first file is written.
    """
    existing = []
    for option, path, suffixes in outputs:
        out = check_output(path, force=force, input_paths=inputs, suffixes=suffixes, option=option)
        if not force and os.path.lexists(out):
            existing.append(f"{option} {out}")
    if existing:
        raise InputError(existing_output_message(existing[0], more=len(existing) - 1))


def precheck(inputs: Sequence[Path], targets: Sequence[Path], dtm_targets: Sequence[Path | None], *,
             units: str | None, estimates: Callable[[], list] | None, dtm_cell_m: float | None,
             extra_bytes_per_point: int = 0,
             trust_data: bool = False) -> list[Planned]:
    """Check every input and output of a job before any file is filtered.

    Args:
      inputs, targets, dtm_targets: one output (and DTM or None) per input; the output paths
        were checked by `check_outputs` already.
      units: the `--units` override, or None (the CRS decides).
      trust_data: `--trust-data` (a header whose point count disagrees with the data passes).
      estimates: the method's memory estimates with its settings (`MethodSetup.memory_estimates`:
        the rasters its settings fix, such as a batch of tiles), checked against the memory
        budget; None: no check. Those
        over a cloud's extent are not: every method filters groups of points far apart
        one by one (`gfjax.tiling.driver`), so the header's box says little of them;
        the method checks them once it has read the points, before anything is written.
      dtm_cell_m: the DTM cell [m] when a DTM is written, else None.
      extra_bytes_per_point: bytes each output point gains (`--instances`: 4).

    Returns:
      The job, one `Planned` per input.

    Raises:
      InputError: a header that cannot be read or holds no points, an unreadable CRS or unit,
        a raster over the memory budget (naming the file and the estimate), or outputs that
        need more space than their folder has free.
    """
    planned = []
    for source, target, dtm_target in zip(inputs, targets, dtm_targets):
        header = las_io.read_header(source, trust_data=trust_data)
        found = las_io.header_crs_units(header, name=str(source), units=units)
        extent = _extent_m(header, found.units.horizontal_m)
        try:
            if estimates is not None:
                limits.check_memory(estimates())
            if dtm_cell_m is not None:
                from gfjax import dtm as dtm_lib  # scipy and matplotlib: only for a DTM

                limits.check_memory([dtm_lib.memory_estimate(extent, dtm_cell_m)])
        except ValueError as err:
            raise InputError(f"{source}: {err}") from None
        planned.append(Planned(source, header, extent, target, dtm_target, found))
    _check_free_space(planned, dtm_cell_m=dtm_cell_m, extra_bytes_per_point=extra_bytes_per_point)
    return planned


def _check_free_space(planned: Sequence[Planned], *, dtm_cell_m: float | None, extra_bytes_per_point: int) -> None:
    """The outputs of each folder must fit in its free space (an estimate from the inputs)."""
    need: dict[Path, float] = {}
    for job in planned:
        outputs = [(job.target, output_bytes(job.header, job.source, job.target,
                                             extra_bytes_per_point=extra_bytes_per_point))]
        if job.dtm_target is not None and dtm_cell_m is not None:
            w, h = (limits.raster_side(e, dtm_cell_m) for e in job.extent_m)
            outputs.append((job.dtm_target, 4.0 * w * h))          # float32, before compression
        for path, size in outputs:
            folder = path.absolute().parent
            if path.exists():                      # replaced: the old file's space comes back
                size = max(0.0, size - path.stat().st_size)
            need[folder] = need.get(folder, 0.0) + size
    by_device: dict[int, tuple[Path, float]] = {}
    for folder, size in need.items():
        try:
            device = os.stat(folder).st_dev
        except OSError:
            continue
        first, total = by_device.get(device, (folder, 0.0))
        by_device[device] = (first, total + size)
    for folder, size in by_device.values():
        try:
            free = shutil.disk_usage(folder).free
        except OSError:
            continue
        if size > free:
            raise InputError(f"{folder}: the outputs need about {byte_size(size)}, only {byte_size(free)} free "
                             "(estimated from the input sizes)")


def _one_line(message: object) -> str:
    return " ".join(str(message).split())


def summary_line(done: Sequence[Path], failed: Sequence[Path], not_started: Sequence[Path], total: int, *,
                 interrupted: Path | None = None) -> str:
    """`gfjax: 2 of 4 files done; failed: b.laz; interrupted: c.laz; not started: d.laz`."""
    parts = [f"gfjax: {len(done)} of {total} files done"]
    if failed:
        parts.append(f"failed: {', '.join(map(str, failed))}")
    if interrupted is not None:
        parts.append(f"interrupted: {interrupted}")
    if not_started:
        parts.append(f"not started: {', '.join(map(str, not_started))}")
    return "; ".join(parts)


def run_files(planned: Sequence[Planned], one: Callable[[Planned], None], *, keep_going: bool,
              report: Callable[[str], None] | None = None) -> int:
    """Run `one` for each planned file, in order. Returns the exit code.

    A single file runs as is (its error ends the command as usual). With several files, a
    file whose `one` raises `InputError` is reported on one line (`gfjax: error: ...`); the
    job stops there (or goes on with `keep_going`) and prints a summary line; exit code 2.
    An internal error stops the job after the summary (exit 1), or with `keep_going` is
    reported and the job goes on, ending with exit code 1. An interrupt (Ctrl-C, SIGTERM,
    SIGHUP) prints the summary and ends the job. A closed output pipe (`BrokenPipeError`) ends
    it quietly, as it ends any command (`gfjax.cli.main`). `report` prints a line on stderr
    (default `print`; a progress bar passes its own writer).
    """
    report = report or (lambda line: print(line, file=sys.stderr))
    if len(planned) == 1:
        one(planned[0])
        return 0
    done: list[Path] = []
    failed: list[Path] = []
    internal = False
    current: Path | None = None
    stopped: Path | None = None
    quiet = False
    try:
        for job in planned:
            current = job.source
            try:
                one(job)
            except BrokenPipeError:
                quiet = True
                raise
            except InputError as err:
                failed.append(job.source)
                report(f"gfjax: error: {_one_line(err)}")
                if not keep_going:
                    break
                continue
            except Exception as err:  # noqa: BLE001 (reported, then re-raised or counted as exit 1)
                failed.append(job.source)
                if not keep_going:
                    raise
                internal = True
                report(f"gfjax: internal error: {job.source}: {type(err).__name__}: {_one_line(err)}")
                continue
            done.append(job.source)
    except BaseException:                       # an interrupt (or an internal error, already in `failed`)
        if current not in failed:
            stopped = current
        raise
    finally:
        finished = set(done) | set(failed) | {stopped}
        not_started = [job.source for job in planned if job.source not in finished]
        if (failed or not_started or stopped is not None) and not quiet:
            hint = " (--keep-going goes on after a failed file)" if failed and not_started and not keep_going else ""
            report(summary_line(done, failed, not_started, len(planned), interrupted=stopped) + hint)
    if internal:
        return 1
    return 2 if failed else 0
