"""Read and write LAS 1.2-1.4 / LAZ files without losing anything (SPEC section 1).

`read` keeps the whole `laspy.LasData` (header, VLRs/EVLRs, scales/offsets, every point
dimension incl. extra bytes) and adds the CRS and the unit factors. `write` is atomic: the
file is written to a temporary name in the target folder, flushed to disk, then renamed over
the target, so a reader never sees a half-written file and a failure leaves nothing behind.
Every bad input raises `InputError` naming the file.
"""
from __future__ import annotations

import glob
import os
from collections.abc import Callable, Iterable
from pathlib import Path

import laspy

from gfjax.errors import InputError
from gfjax.io import crs as crs_lib
from gfjax.io import units as units_lib
from gfjax.io.atomic import atomic_output, check_output, is_temporary
from gfjax.io.cloud import Cloud

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
_SIGNATURE = b"LASF"
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
        path = Path(text)
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.is_file() and _is_las_name(p))
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


def _check_readable(path: Path) -> None:
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a LAS/LAZ file")
    try:
        with open(path, "rb") as f:
            signature = f.read(4)
    except OSError as err:
        raise InputError(f"{path}: cannot open ({err.strerror})") from None
    if signature != _SIGNATURE:
        raise InputError(f"{path}: not a LAS/LAZ file (signature {signature!r}, expected {_SIGNATURE!r})")


def read_header(path: str | os.PathLike) -> laspy.LasHeader:
    """The header of a LAS/LAZ file (no points read); checks it exists, is LAS and has points."""
    path = Path(path)
    _check_readable(path)
    try:
        with laspy.open(path, laz_backend=LAZ_BACKENDS, read_evlrs=False) as reader:
            header = reader.header
    except (laspy.errors.LaspyException, OSError, ValueError, EOFError) as err:
        raise InputError(f"{path}: not a valid LAS/LAZ header ({err})") from None
    if header.point_count == 0:
        raise InputError(f"{path}: the file holds no points")
    return header


def _resolve_units(header: laspy.LasHeader, *, name: str, units: str | units_lib.Units | None):
    override = units_lib.parse_units_option(units) if isinstance(units, str) else units
    try:
        crs = crs_lib.parse_crs(header, name=name)
    except InputError:
        if override is None:
            raise
        crs = None  # unreadable CRS, but the user stated the units
    if override is not None:
        return crs, override
    horizontal_m, vertical_m = crs_lib.geokey_units_m(header)
    return crs, units_lib.units_from_crs(crs, name=name, horizontal_unit_m=horizontal_m,
                                         vertical_unit_m=vertical_m)


def read(path: str | os.PathLike, *, units: str | units_lib.Units | None = None) -> Cloud:
    """Read a LAS 1.2-1.4 or LAZ file whole, with its CRS and unit factors.

    Args:
      path: the file. LAZ is decompressed with lazrs.
      units: `"m"`, `"ft"` or `"us-ft"` (or a `Units`) to override the units of the CRS; by
        default they come from the CRS, and a file without a CRS is taken as metres.

    Returns:
      A `Cloud` whose `las` holds every header field, VLR/EVLR and point dimension.

    Raises:
      InputError: missing file, not LAS/LAZ, truncated or corrupt data, zero points, an
        unreadable CRS (without `units`), a geographic CRS in degrees (without `units`).
    """
    path = Path(path)
    read_header(path)
    try:
        with laspy.open(path, laz_backend=LAZ_BACKENDS) as reader:
            compressed = reader.header.are_points_compressed
            las = reader.read()
    except (laspy.errors.LaspyException, RuntimeError, OSError, ValueError, EOFError) as err:
        if _is_compressed(path):
            raise InputError(f"{path}: truncated or corrupt LAZ data (decompression failed: {err})") from None
        raise InputError(f"{path}: truncated or corrupt LAS data ({err})") from None
    expected = las.header.point_count
    if len(las.points) != expected:
        kind = "LAZ" if compressed else "LAS"
        raise InputError(f"{path}: truncated {kind} file: header says {expected} points, "
                         f"the file holds {len(las.points)}")
    crs, units_found = _resolve_units(las.header, name=str(path), units=units)
    return Cloud(las=las, path=path, horizontal_unit_m=units_found.horizontal_m,
                 vertical_unit_m=units_found.vertical_m, crs=crs, units_source=units_found.source)


def _is_compressed(path: Path) -> bool:
    """True when `path` holds compressed points (LAZ), judged from its header bits or suffix."""
    try:
        with laspy.open(path, laz_backend=LAZ_BACKENDS, read_evlrs=False) as reader:
            return bool(reader.header.are_points_compressed)
    except (laspy.errors.LaspyException, OSError, ValueError, EOFError):
        return path.suffix.lower() == ".laz"


def write(cloud: Cloud, path: str | os.PathLike, *, force: bool = False,
          input_paths: Iterable[str | os.PathLike] = (),
          before_commit: Callable[[], None] | None = None) -> Path:
    """Write `cloud.las` to `path` atomically; LAZ (lazrs) when the suffix is `.laz`.

    Nothing but what `cloud.las` holds is written: the header, VLRs/EVLRs, scales/offsets and
    every point dimension are those read. Refuses to overwrite `cloud.path` or any of
    `input_paths` unless `force`. `before_commit` runs once the points are written, before the
    file is renamed into place: if it raises, `path` is not written (a companion file, such as
    `gfjax filter --dtm`'s DTM, is written there so that neither exists without the other).

    Returns:
      The path written.

    Raises:
      InputError: see `check_output`; or the file could not be written.
    """
    inputs = [*input_paths, *([cloud.path] if cloud.path is not None else [])]
    compress = Path(path).suffix.lower() == ".laz"
    backends = _compressors(cloud.las.point_format.id, Path(path)) if compress else None
    with atomic_output(path, force=force, input_paths=inputs, suffixes=LAS_SUFFIXES) as tmp:
        with open(tmp, "w+b") as f:  # readable: laspy re-reads the header to add EVLRs
            cloud.las.write(f, do_compress=compress, laz_backend=backends)
        if before_commit is not None:
            before_commit()
    return Path(path)


def _compressors(point_format_id: int, out: Path) -> tuple[laspy.LazBackend, ...]:
    if point_format_id not in LOSSY_WITH_LAZRS:
        return LAZ_BACKENDS
    if laspy.LazBackend.Laszip.is_available():
        return (laspy.LazBackend.Laszip,)
    raise InputError(f"{out}: point format {point_format_id} (wave packets) cannot be written as LAZ "
                     "without loss by lazrs; install the laszip package or write .las")


def header_units(header: laspy.LasHeader, *, name: str,
                 units: str | units_lib.Units | None = None) -> units_lib.Units:
    """The unit factors `read` would give a file with this header (`units` overrides the CRS),
    without reading its points: checks that its CRS and units are readable.

    Raises:
      InputError: as `read` for an unreadable CRS or a geographic CRS in degrees.
    """
    return _resolve_units(header, name=name, units=units)[1]
