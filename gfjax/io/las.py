"""Read and write LAS 1.2-1.4 / LAZ files without losing anything (SPEC section 1).

`read` keeps the whole `laspy.LasData` (header, VLRs/EVLRs, scales/offsets, every point
dimension incl. extra bytes) and adds the CRS and the unit factors. `write` is atomic: the
file is written to a temporary name in the target folder, flushed to disk, then renamed over
the target, so a reader never sees a half-written file and a failure leaves nothing behind.
Every bad input raises `InputError` naming the file.
"""
from __future__ import annotations

import copy
import glob
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import laspy
import numpy as np

from gfjax.errors import InputError
from gfjax.io import asprs, copc, copc_writer, point_store
from gfjax.io import crs as crs_lib
from gfjax.io import units as units_lib
from gfjax.io.atomic import atomic_output, is_temporary
from gfjax.io.cloud import Cloud
from gfjax.io.las_layout import INT32_MAX, INT32_MIN, WRITTEN_AS, Layout, check_layout

if TYPE_CHECKING:
    import pyproj

LAS_SUFFIXES = (".las", ".laz")
# lazrs (Rust) for LAZ, multi-threaded when available; laszip is only used by the tests.
LAZ_BACKENDS = (laspy.LazBackend.LazrsParallel, laspy.LazBackend.Lazrs)
# lazrs 0.8.2 compresses the wave-packet fields of point formats 9/10 lossily (wavepacket
# offset/size/location and x_t/y_t/z_t change; tests/io/test_las.py keeps the evidence), so
# these two are compressed by LASzip when the `laszip` package is installed, and refused
# otherwise. LASzip then stamps its own `generating_software` and leaves the optional min/max
# statistics of the Extra Bytes VLR unset; every point byte is kept. (lazrs writes formats 4/5
# losslessly, but with a WAVEPACKET13 item version that LASzip 3.5 does not read.)
LOSSY_WITH_LAZRS = frozenset({9, 10})
_GLOB_CHARS = frozenset("*?[")


def _is_las_name(path: Path) -> bool:
    """A `.las`/`.laz` name that is not a gfjax temporary file (`gfjax.io.atomic`)."""
    return path.suffix.lower() in LAS_SUFFIXES and not is_temporary(path)


def expand_inputs(patterns: Iterable[str | os.PathLike]) -> list[Path]:
    """Input files from file names, folders and glob patterns.

    A folder gives its `.las`/`.laz` files (not recursive); a glob (`*`, `?`, `[`, `**`) gives
    the `.las`/`.laz` files it matches; a file name is taken as is. Temporary files of gfjax
    writers (`gfjax.io.atomic`, also those of killed runs) are never inputs. Folders and globs are sorted
    by name; argument order is kept; a file named twice is kept once (first occurrence).

    Raises:
      InputError: no pattern, a name that does not exist, a folder or glob without LAS files.
    """
    found: list[Path] = []
    for pattern in patterns:
        text = os.fspath(pattern)
        if text == "":
            raise InputError("'': empty input name")
        path = Path(text)
        try:
            os.stat(text)
        except (FileNotFoundError, NotADirectoryError):
            pass
        except OSError as err:  # a name too long, a loop of links, a folder we may not enter
            raise InputError(f"{text}: cannot open ({err.strerror or err})") from None
        if path.is_dir():
            try:
                files = sorted(p for p in path.iterdir() if p.is_file() and _is_las_name(p))
            except OSError as err:
                raise InputError(f"{path}: cannot list the folder ({err.strerror or err})") from None
            if not files:
                raise InputError(f"{path}: folder holds no .las/.laz files")
        elif path.exists():
            if is_temporary(path):
                raise InputError(f"{path}: a temporary file of an unfinished gfjax write, not an input")
            files = [path]
        elif _GLOB_CHARS & set(text):
            files = sorted(Path(p) for p in glob.glob(text, recursive=True)
                           if Path(p).is_file() and _is_las_name(Path(p)))
            if not files:
                raise InputError(f"{text}: no .las/.laz file matches")
        else:
            raise InputError(f"{text}: no such file or folder")
        found.extend(files)
    if not found:
        raise InputError("no input files given")
    unique: dict[str, Path] = {}
    for path in found:
        unique.setdefault(os.path.realpath(path), path)
    return list(unique.values())


def _count_problem(path: Path, layout: Layout) -> str:
    kind = "LAZ" if layout.compressed else "LAS"
    header, data = layout.header_count, layout.data_count
    if data < header:
        return (f"{path}: truncated {kind} file: header says {header} points, the file holds {data}; "
                f"filter --trust-data uses the {data} points present")
    return (f"{path}: header says {header} points, the {kind} data holds {data}; "
            f"filter --trust-data uses all {data} points")


def check_file(path: str | os.PathLike, *, trust_data: bool = False) -> Layout:
    """Check a LAS/LAZ file before laspy reads it (`gfjax.io.las_layout.check_layout`).

    Raises:
      InputError: not a regular LAS/LAZ file, a header that does not fit the file, or (unless
        `trust_data`) a point count that disagrees with the data.
    """
    path = Path(path)
    layout = check_layout(path)
    if layout.data_count != layout.header_count and not trust_data:
        raise InputError(_count_problem(path, layout))
    return layout


def read_header(path: str | os.PathLike, *, trust_data: bool = False, allow_empty: bool = False) -> laspy.LasHeader:
    """The header of a LAS/LAZ file (no points read); checks it is a regular LAS/LAZ file whose
    header fits its size, whose point count matches the data (unless `trust_data`) and which
    has points (unless `allow_empty`: `gfjax info` describes an empty file)."""
    return _read_header(Path(path), trust_data=trust_data, allow_empty=allow_empty)[0]


def _read_header(path: Path, *, trust_data: bool, allow_empty: bool = False) -> tuple[laspy.LasHeader, Layout]:
    layout = check_file(path, trust_data=trust_data)
    try:
        with laspy.open(path, laz_backend=LAZ_BACKENDS, read_evlrs=False) as reader:
            header = reader.header
    except Exception as err:  # noqa: BLE001 (laspy parsing the user's bytes: a bad file, not a bug)
        raise InputError(f"{path}: not a valid LAS/LAZ header ({type(err).__name__}: {err})") from None
    if layout.data_count == 0 and not allow_empty:
        raise InputError(f"{path}: the file holds no points")
    return header, layout


class CRSUnits(NamedTuple):
    """What a file says of its coordinates.

    Attributes:
      crs: its CRS, or None when it states none (or its CRS records are empty or unreadable).
      units: the unit factors used (`--units`, else from the CRS, else metres assumed).
      crs_problem: CRS records the file holds that gave no CRS, in words ("empty WKT CRS
        record", `gfjax.io.crs.read_crs`), or None. Such a file is read as one without a CRS.
    """

    crs: pyproj.CRS | None
    units: units_lib.Units
    crs_problem: str | None


def header_crs_units(header: laspy.LasHeader, *, name: str,
                     units: str | units_lib.Units | None = None) -> CRSUnits:
    """The CRS and unit factors `read` gives a file with this header (`units` overrides the
    CRS's units), without reading its points.

    Raises:
      InputError: an unknown `units`. `gfjax.io.units.UnusableUnits` (an InputError): a
        geographic CRS in degrees or an axis without a linear unit, and no `units`.
    """
    override = units_lib.parse_units_option(units) if isinstance(units, str) else units
    crs, problem = crs_lib.read_crs(header)
    if override is not None:
        return CRSUnits(crs, override, problem)
    horizontal_m, vertical_m = crs_lib.geokey_units_m(header)
    found = units_lib.units_from_crs(crs, name=name, horizontal_unit_m=horizontal_m,
                                     vertical_unit_m=vertical_m, crs_problem=problem)
    return CRSUnits(crs, found, problem)


def read_points(path: str | os.PathLike, *, trust_data: bool = False, allow_empty: bool = False,
                stored: str | os.PathLike | None = None) -> laspy.LasData:
    """Read a LAS 1.0-1.4 or LAZ file whole, checked as `read` checks it, without its units:
    what `gfjax info` describes (a file with no points when `allow_empty`, or in degrees).
    With `stored`, its points are that `gfjax.io.point_store` of them (the file's checked
    records, kept when a survey read it: only the header and EVLRs are read from the file).

    Raises:
      InputError: as `read`, except for the CRS and the units.
    """
    path = Path(path)
    _, layout = _read_header(path, trust_data=trust_data, allow_empty=allow_empty)
    kind = "LAZ" if layout.compressed else "LAS"
    try:
        with laspy.open(path, laz_backend=LAZ_BACKENDS) as reader:
            reader.header.point_count = layout.data_count
            if stored is None:
                las = reader.read()
            else:
                header = reader.header
                las = laspy.LasData(header=header, points=laspy.ScaleAwarePointRecord(
                    point_store.load(stored), header.point_format, header.scales, header.offsets))
    except MemoryError:
        raise  # a file too large for this machine is not a corrupt one
    except Exception as err:  # noqa: BLE001 (laspy/lazrs decoding the user's bytes: a bad file, not a bug)
        detail = f"decompression failed: {err}" if layout.compressed else str(err)
        raise InputError(f"{path}: truncated or corrupt {kind} data ({detail})") from None
    if len(las.points) != layout.data_count:
        raise InputError(f"{path}: truncated {kind} file: header says {layout.header_count} points, "
                         f"the file holds {len(las.points)}")
    check_int32_limits(path, las.points)
    return las


def read(path: str | os.PathLike, *, units: str | units_lib.Units | None = None,
         trust_data: bool = False, classes: asprs.ClassRules = asprs.DEFAULT_RULES,
         stored: str | os.PathLike | None = None) -> Cloud:
    """Read a LAS 1.0-1.4 or LAZ file whole, with its CRS and unit factors.

    Args:
      path: the file. LAZ is decompressed with lazrs.
      units: `"m"`, `"ft"` or `"us-ft"` (or a `Units`) to override the units of the CRS; by
        default they come from the CRS, and a file without a CRS (or whose CRS records are
        empty or unreadable: `header_crs_units`) is taken as metres.
      trust_data: when the header's point count disagrees with the points the file holds, read
        the points present (the cloud's header then counts them) instead of raising.
      classes: which classes filters ignore and which keep their class (`Cloud.classes`).
      stored: the file's points kept by a survey's catalog (`read_points`), or None.

    Returns:
      A `Cloud` whose `las` holds every header field, VLR/EVLR and point dimension.

    Raises:
      InputError: missing file, not a regular file, not LAS/LAZ, a header that does not fit
        the file (`gfjax.io.las_layout`), a point count the data contradicts (unless
        `trust_data`), truncated or corrupt data, zero points, coordinates at the int32 limits,
        a geographic CRS in degrees (without `units`).
    """
    las = read_points(path, trust_data=trust_data, stored=stored)
    found = header_crs_units(las.header, name=str(path), units=units)
    return Cloud(las=las, path=Path(path), horizontal_unit_m=found.units.horizontal_m,
                 vertical_unit_m=found.units.vertical_m, crs=found.crs, units_source=found.units.source,
                 classes=classes)


def check_int32_limits(path: Path, points) -> None:
    """Refuse points (a laspy point record) whose stored integer X/Y/Z sits at the int32
    limits: the coordinates overflowed (or were clamped) when the file was written, so they
    do not say where the point is."""
    for axis in ("X", "Y", "Z"):
        values = np.asarray(points[axis])
        if len(values) == 0:
            continue
        low, high = int(values.min()), int(values.max())
        if low <= INT32_MIN or high >= INT32_MAX:
            limit = INT32_MIN if low <= INT32_MIN else INT32_MAX
            raise InputError(f"{path}: stored {axis} integers reach the int32 limit {limit} (coordinates "
                             "overflowed the file's scale and offset)")


def write(cloud: Cloud, path: str | os.PathLike, *, force: bool = False,
          input_paths: Iterable[str | os.PathLike] = (),
          before_commit: Callable[[], None] | None = None, exclusive: bool = False) -> Path:
    """Write `cloud.las` to `path` atomically; LAZ (lazrs) when the suffix is `.laz`.

    Nothing but what `cloud.las` holds is written: the header, VLRs/EVLRs, scales/offsets and
    every point dimension are those read. Refuses to overwrite `cloud.path` or any of
    `input_paths` unless `force`. `before_commit` runs once the points are written, before the
    file is renamed into place: if it raises, `path` is not written (a companion file, such as
    `gfjax filter --dtm`'s DTM, is written there so that neither exists without the other).
    With `exclusive`, an existing `path` is never replaced, even one another process wrote
    since the work began (the command line without `--force`): InputError, nothing written.

    Returns:
      The path written.

    Raises:
      InputError: see `check_output`; or the file could not be written.
    """
    inputs = [*input_paths, *([cloud.path] if cloud.path is not None else [])]
    as_copc = copc_writer.is_copc_name(path)
    compress = Path(path).suffix.lower() == ".laz" and not as_copc
    backends = _compressors(cloud.las.point_format.id, Path(path)) if compress else None
    with atomic_output(path, force=force, input_paths=inputs, suffixes=LAS_SUFFIXES, exclusive=exclusive) as tmp:
        if as_copc:
            copc_writer.write(cloud.las, tmp, name=str(path), wkt=crs_lib.crs_wkt(cloud))
        else:
            _write_file(cloud, path, tmp, compress=compress, backends=backends)
        if before_commit is not None:
            before_commit()
    return Path(path)


def _write_file(cloud: Cloud, path, tmp: Path, *, compress: bool, backends) -> None:
    """`cloud.las` as LAS/LAZ into the temporary `tmp` of output `path` (`write`)."""
    with open(tmp, "w+b") as raw:  # readable: laspy re-reads the header to add EVLRs
        f = _KeepWriteError(raw)
        try:
            _write_las(cloud.las, f, compress=compress, backends=backends)
        except UnicodeError as err:
            raise InputError(f"{path}: cannot write the text fields of {cloud.name} unchanged: LAS text "
                             f"is ASCII ({err})") from None
        except Exception:
            if f.error is not None:  # a full disk under lazrs: the OSError, so exit 2
                raise f.error from None
            raise


def _write_las(las: laspy.LasData, f, *, compress: bool, backends) -> None:
    """`las.write(f)`, keeping header and VLR text that is not ASCII byte for byte.

    laspy reads a text field it cannot decode as ASCII as raw bytes, and by default refuses to
    write such bytes back; `surrogateescape` lets it check them without error and write them
    unchanged. (A VLR user id is checked strictly whatever the setting: `write` reports it.)
    """
    header, evlrs = writable(las.header, las.evlrs)
    with laspy.LasWriter(f, header, do_compress=compress, laz_backend=backends, closefd=False,
                         encoding_errors="surrogateescape") as writer:
        writer.write_points(las.points)
        copc_writer.keep_extra_bytes_statistics(header, writer.header)
        if header.version.minor >= 4 and evlrs:
            writer.write_evlrs(evlrs)


def written_version(header: laspy.LasHeader) -> tuple[int, int] | None:
    """The version a file of `header` is written as when laspy cannot write its own (LAS 1.0:
    1.2, `las_layout.WRITTEN_AS`); None when it is written as read."""
    return WRITTEN_AS.get((header.version.major, header.version.minor))


def writable(header: laspy.LasHeader, evlrs) -> tuple[laspy.LasHeader, Any]:
    """`header` and `evlrs` as laspy can write them back: without COPC's layout records
    (`copc.without_layout`), a LAS 1.0 header as LAS 1.2 (`written_version`). A copy where
    anything changes; `header` and `evlrs` themselves otherwise."""
    new, evlrs = copc.without_layout(header, evlrs)
    version = written_version(new)
    if version is not None:
        new = copy.deepcopy(new) if new is header else new
        new.version = laspy.header.Version(*version)
    return new, evlrs


class _KeepWriteError:
    """A binary file that remembers the `OSError` its `write` raised (e.g. ENOSPC, a full disk).

    lazrs turns an error of the Python file it writes to into `LazrsError("Failed to call
    write")`, dropping the errno; `write` re-raises the remembered `OSError` instead, which
    `atomic_output` reports as one line (and removes the temporary file).
    """

    def __init__(self, f):
        self._f = f
        self.error: OSError | None = None

    def write(self, data) -> int:
        try:
            return self._f.write(data)
        except OSError as err:
            self.error = err
            raise

    def __getattr__(self, name: str):
        return getattr(self._f, name)


def _compressors(point_format_id: int, out: Path) -> tuple[laspy.LazBackend, ...]:
    if point_format_id not in LOSSY_WITH_LAZRS:
        return LAZ_BACKENDS
    if laspy.LazBackend.Laszip.is_available():
        return (laspy.LazBackend.Laszip,)
    raise InputError(f"{out}: point format {point_format_id} (wave packets) cannot be written as LAZ "
                     "without loss by lazrs; install the laszip package or write .las")


def header_units(header: laspy.LasHeader, *, name: str,
                 units: str | units_lib.Units | None = None) -> units_lib.Units:
    """The unit factors `read` would give a file with this header (`header_crs_units`).

    Raises:
      InputError: as `read` for a geographic CRS in degrees.
    """
    return header_crs_units(header, name=name, units=units).units
