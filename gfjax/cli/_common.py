"""Options and checks shared by the subcommands: numbers, units, method selection, outputs."""
from __future__ import annotations

import argparse
import functools
import math
import os
import shutil
import sys
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from gfjax.errors import InputError
from gfjax.io.units import UNIT_CHOICES
from gfjax.limits import Range
from gfjax.method import Method

TIF_SUFFIXES = (".tif", ".tiff")
NEIGHBOURS_GROUND_M = 50.0      # neighbour files' ground around a file, for its TIN [m] (hag, dtm)
POINTS_OUTPUT_HELP = ("output .las/.laz file (named .copc.laz: written as COPC), or an existing folder for "
                      "several inputs")
_NAMED = 3                  # files a warning names before it counts the rest

# The valid range of every numeric option that belongs to a command rather than to a method
# (`--set` keys, `--tile-size`, `--buffer` and `--cell` have theirs in the method's and the
# DTM's RANGES). Parsed and checked by `ranged(option)`; listed in the table of `docs/cli.md`.
RANGES: dict[str, Range] = {
    "--ground-class": Range(0, 255, integer=True),
    "--reference-class": Range(0, 255, integer=True),
    "--steps": Range(1, 100_000, integer=True),
    "--folds": Range(0, 1000, integer=True),
    "--block": Range(0, 100_000, low_open=True, unit="m"),
    "--prior": Range(0, 1e6),
    "--epochs": Range(1, 10_000, integer=True),
    "--batch": Range(1, 1024, integer=True),
    "--lr": Range(0, 10, low_open=True),
    "--seed": Range(0, 2**32 - 1, integer=True),
    "--min-patches-per-file": Range(0, 100_000, integer=True),
    "--max-patches-per-file": Range(0, 100_000, integer=True),
    "--thin-copies": Range(0, 100, integer=True),
    "--repeat": Range(1, 10_000, integer=True),
    "--timeout": Range(0, 1e7, low_open=True, unit="s"),
}
DEFAULTS: dict[str, object] = {}


def ranged(option: str) -> Callable[[str], float | int]:
    """argparse type of `option`: a number in `RANGES[option]` (an int for integer ranges)."""
    allowed = RANGES[option]

    def parse(text: str) -> float | int:
        try:
            value = int(text) if allowed.integer else float(text)
        except ValueError:
            kind = "a whole number" if allowed.integer else "a number"
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}") from None
        if not allowed.contains(value):
            raise argparse.ArgumentTypeError(f"must be {allowed.text()}, got {text}")
        return value

    parse.__name__ = option.lstrip("-")
    return parse


def number(text: str) -> float:
    """argparse type: any number, `inf` included (its range is checked where the option's
    range lives, e.g. `gfjax.dtm.build.check_options`); not NaN."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if math.isnan(value):
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (a cell size, a tile size) [m]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def positive_int(text: str) -> int:
    """argparse type: a whole number >= 1 (steps, folds, repeats)."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def workers_count(text: str) -> int | str:
    """argparse type of `--workers`: a whole number >= 1, or "auto"."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return positive_int(text)
    except argparse.ArgumentTypeError as err:
        raise argparse.ArgumentTypeError(f"{err} (or auto)") from None


def nonnegative_int(text: str) -> int:
    """argparse type: a whole number >= 0."""
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def nonnegative_float(text: str) -> float:
    """argparse type: a finite number >= 0 (a buffer, a maximum edge) [m]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text}")
    return value


def add_units_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--units", choices=tuple(UNIT_CHOICES), default=None,
                        help="coordinate units of the input, overriding its CRS "
                             "(default: from the CRS; metres when the file has none)")


def add_method_options(parser: argparse.ArgumentParser, *, method_help: str, default_method: bool = False,
                       tiling: bool = False) -> None:
    """--method, --preset, --set key=value (repeatable), --params params.json.

    The help ends with each method's presets (`method_table`). `default_method`: the command
    runs `gfjax.methods.DEFAULT_METHOD` without --method (the help names it); `tiling`: it
    takes --tile-size / --buffer (the help lists the methods that do).
    """
    from gfjax.methods import DEFAULT_METHOD, names

    default = f" (default {DEFAULT_METHOD})" if default_method else ""
    parser.add_argument("--method", default=None, metavar="NAME",
                        help=f"{method_help}{default}: {', '.join(names())}")
    parser.add_argument("--preset", default=None, metavar="NAME",
                        help="a named set of option values of the method (listed below)")
    # Built only when the help is printed: it imports every method (`gfjax.cli.main._Parser`).
    parser.epilog = functools.partial(method_table, default_method=default_method, tiling=tiling)
    parser.add_argument("--set", dest="set_values", action="append", default=[], metavar="KEY=VALUE",
                        help="override one Config/Params value in metres, e.g. --set cell_m=0.5 "
                             "(repeatable; wins over --preset and --params)")
    parser.add_argument("--params", default=None, metavar="PARAMS.json",
                        help="fitted thresholds written by `gfjax tune`")
    add_model_option(parser)


def method_table(*, default_method: bool = False, tiling: bool = False) -> str:
    """The end of `--help` for the commands that run a method: each method's presets (its
    `PRESETS`), the default method marked when `default_method`, and with `tiling` the methods
    that take `--tile-size` / `--buffer` (`Method.tiles`), with the defaults.

    Imports every method package, and so JAX (about a second): called only to print help.
    """
    from gfjax import methods

    width = max(shutil.get_terminal_size().columns - 2, 60)
    lines = ["methods (--method NAME) and their presets (--preset NAME):"]
    tiled = []
    for name in methods.names():
        label = f"  {name}{' (default)' if default_method and name == methods.DEFAULT_METHOD else ''}"
        try:
            method = methods.get(name)
        except (InputError, ImportError):
            lines.append(f"{label}: not available in this build")
            continue
        presets = ", ".join(method.presets) or "none"
        lines.append(textwrap.fill(f"{label}: {presets}", width=width, subsequent_indent=" " * 6,
                                   break_on_hyphens=False))
        if method.tiles:
            tiled.append(name)
    if tiling:
        from gfjax.tiling.tiles import Tiling

        taken = ", ".join(tiled) if tiled else "none"
        lines.append(textwrap.fill(f"--tile-size and --buffer apply to the methods that tile: {taken} (default "
                                   f"{Tiling.tile_size_m:g} m tiles, {Tiling.buffer_m:g} m buffers); the other "
                                   "methods refuse them.", width=width, break_on_hyphens=False))
    return "\n".join(lines)


def add_model_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", default=None, metavar="MODEL.eqx",
                        help="SparseGF network written by `gfjax train` (default: the model shipped in gfjax)")


def crs_warning(found: Sequence[tuple[Path, Any]], *, metres_matter: bool = True) -> str | None:
    """One warning line for a whole run about its inputs' CRSs, or None when there is nothing to say.

    Args:
      found: `(path, gfjax.io.las.CRSUnits)` of every input.
      metres_matter: the command works in metres (filters, DTMs): files whose coordinates are
        taken as metres for want of a CRS (and of `--units`) are named too.

    The line names the files whose CRS records are empty or unreadable (read as files without
    a CRS) and, when metres matter, those without a CRS, then says how to give the units;
    at most three files of each kind are named, then a count.
    """
    unique: dict[Path, Any] = {}
    for path, f in found:               # an input may also be a reference (`gfjax eval`)
        unique.setdefault(path, f)
    found = list(unique.items())
    ignored = [(path, f.crs_problem) for path, f in found if f.crs_problem is not None]
    bare = [path for path, f in found if f.crs is None and f.crs_problem is None and f.units.assumed]
    assumed = metres_matter and any(f.units.assumed for _, f in found)
    parts = [f"{path}: {problem}, read as no CRS" for path, problem in ignored[:_NAMED]]
    if len(ignored) > _NAMED:
        parts.append(f"{len(ignored) - _NAMED} more files with such CRS records")
    if assumed and bare:
        parts.append(f"{_some(bare)}: no CRS")
    if not parts:
        return None
    units = "; coordinates taken as metres (pass --units m|ft|us-ft if they are not)" if assumed else ""
    return f"gfjax: warning: {'; '.join(parts)}{units}"


def _some(paths: Sequence[Path]) -> str:
    names = ", ".join(map(str, paths[:_NAMED]))
    return names if len(paths) <= _NAMED else f"{names} and {len(paths) - _NAMED} more files"


def say_crs_warning(found: Sequence[tuple[Path, Any]], *, metres_matter: bool = True) -> None:
    """Print `crs_warning` on stderr, if any: once per run, before any file is read whole."""
    line = crs_warning(found, metres_matter=metres_matter)
    if line is not None:
        print(line, file=sys.stderr)


def check_written_forms(found: Sequence[tuple[Path, Any, Path]]) -> None:
    """Refuse, before any work, an input (`(path, laspy header, output path)`) that its output
    cannot hold, and say once on stderr which are written in another form than theirs: LAS 1.0
    as 1.2 (`gfjax.io.las.written_version`), a COPC output (`.copc.laz`) as LAS 1.4 in point
    format 6-8 (`gfjax.io.copc_writer`).

    Raises:
      InputError: a COPC output of a point format that COPC cannot hold (waveform formats).
    """
    from gfjax.io import copc_writer
    from gfjax.io import las as las_io

    by_change: dict[str, list[Path]] = {}
    for path, header, target in found:
        copc_writer.check_writable(header, target, name=str(path))
        old = f"LAS {header.version.major}.{header.version.minor}"
        if copc_writer.is_copc_name(target):
            fmt = header.point_format.id
            new = copc_writer.written_format(header)
            if (header.version.major, header.version.minor, fmt) != (1, 4, new):
                by_change.setdefault(f"{old} point format {fmt}, written as COPC in LAS 1.4 point format {new} "
                                     "(COPC's formats); every point and dimension kept, in the octree's order",
                                     []).append(path)
            continue
        version = las_io.written_version(header)
        if version is not None:
            by_change.setdefault(f"{old}, written as LAS {version[0]}.{version[1]} (laspy writes no {old}); "
                                 f"points and classes are as in {old}", []).append(path)
    for change, paths in by_change.items():
        print(f"gfjax: note: {_some(paths)}: {change}", file=sys.stderr)


def check_inputs(paths: Sequence[Path], *, units: str | None, metres_matter: bool = True) -> list:
    """Read every input's header, CRS and units before any work (`gfjax.io.las.read_header`,
    `header_crs_units`), and say once what was assumed of their CRSs (`say_crs_warning`).

    Returns:
      The headers, one per path.

    Raises:
      InputError: a file that is not a readable LAS/LAZ file with points, a geographic CRS
        (without `units`).
    """
    from gfjax.io import las as las_io

    headers, found = [], []
    for path in paths:
        header = las_io.read_header(path)
        found.append((path, las_io.header_crs_units(header, name=str(path), units=units)))
        headers.append(header)
    say_crs_warning(found, metres_matter=metres_matter)
    return headers


def class_list(text: str) -> tuple[int, ...]:
    """argparse type of `--ignore-class` / `--keep-class`: `"6,9,17"` -> `(6, 9, 17)`, ASPRS codes
    0-255."""
    codes = []
    for item in text.split(","):
        item = item.strip()
        try:
            code = int(item)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{item!r} is not a class code (a comma-separated list of "
                                             "integers 0-255, e.g. 6,9,17)") from None
        if not 0 <= code <= 255:
            raise argparse.ArgumentTypeError(f"class {code} is not an ASPRS class code (0-255)")
        codes.append(code)
    return tuple(codes)


def parse_set_values(items: Sequence[str]) -> dict[str, str]:
    """`["cell_m=0.5", ...]` -> `{"cell_m": "0.5"}`; a later key wins."""
    values: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise InputError(f"--set {item!r}: expected KEY=VALUE, e.g. --set cell_m=0.5")
        values[key.strip()] = value.strip()
    return values


def load_params_file(path: str | os.PathLike) -> dict[str, Any]:
    """A params.json of `gfjax tune` (`gfjax.io.params_file.read_params`), errors as `--params`."""
    from gfjax.io.params_file import read_params

    return read_params(path, option="--params")


class MethodSetup(NamedTuple):
    """A method (`gfjax.method.Method`), the Config/Params the options give it, and further
    keyword arguments of its `filter` (SparseGF's `model`, a tiled method's `tiling`)."""

    method: Method
    config: Any
    params: Any
    options: dict | None = None
    fixed: frozenset[str] | None = None      # fields the options set; None: every field settled
    settled: Any = None                      # what `settle` chose (`gfjax.adaptive.Settled`)

    @property
    def name(self) -> str:
        return self.method.name

    def filter(self, cloud, **kwargs):
        """The method on `cloud`; the values the options left open follow the cloud first
        (`settle`), and the run is the one of `gfjax.adaptive.run` (low outliers hidden for a
        method that hides them, ground spikes dropped after, `Result.settled` what was chosen),
        as a Python call without a `config` makes it. With `--preset fixed`, the method alone."""
        from gfjax import adaptive

        setup = self.settle(cloud, returns=kwargs.get("returns", "all"))
        return adaptive.run(self.method.filter, cloud, setup.settled, config=setup.config, params=setup.params,
                            hides_low_outliers=self.method.hides_low_outliers, **(self.options or {}), **kwargs)

    def settle(self, cloud, *, returns: str = "all") -> MethodSetup:
        """This setup with the values the options left open set from `cloud` (the method's
        `adapt`, `gfjax.adaptive`), and fixed from then on (a survey settles once, on all of
        its points, so every tile shares the values); itself when nothing is left open."""
        from gfjax import adaptive

        rule = self.method.adapt
        if self.fixed is None or rule is None:
            return self
        settled = adaptive.settle_cloud(rule, cloud, self.config, self.params, fixed=self.fixed, returns=returns)
        return self.fixed_at(settled)

    def fixed_at(self, settled) -> MethodSetup:
        """This setup with `settled`'s config and params, nothing left open."""
        return self._replace(config=settled.config, params=settled.params, fixed=None, settled=settled)

    @property
    def tiling(self):
        """The `--tile-size` / `--buffer` tiling (`gfjax.Tiling`), None for the method's default."""
        return (self.options or {}).get("tiling")

    @property
    def lattice(self):
        """The lattice a survey runs tile by tile (`gfjax.methods.lattice`), or None."""
        from gfjax import methods

        return methods.lattice(self.method, self.config, self.tiling)

    def memory_estimates(self) -> list:
        """The method's `Config.memory_estimates()` with its tiling (`gfjax.methods.memory_estimates`)."""
        from gfjax import methods

        return methods.memory_estimates(self.config, self.tiling)


def method_setup(args: argparse.Namespace, *, tiling: tuple[float | None, float | None] = (None, None)) -> MethodSetup:
    """Resolve --method / --params / --preset / --set into a method and its Config/Params.

    The method is `--method`, else the params file's method, else `DEFAULT_METHOD`. `tiling`:
    the `--tile-size` and `--buffer` values (None: not given), for a method that tiles
    (`Method.tiles`). Every value is range-checked (`gfjax.limits`) before any file is
    read.
    """
    from gfjax import adaptive, methods

    params_file = load_params_file(args.params) if args.params is not None else None
    name = args.method or (params_file["method"] if params_file else methods.DEFAULT_METHOD)
    if params_file and not args.method and name not in methods.PACKAGES:
        raise InputError(f"--params {args.params}: fitted for method {name!r}, which gfjax does not have; "
                         f"choose from {', '.join(methods.PACKAGES)}")
    if params_file and params_file["method"] != name:
        raise InputError(f"--params {args.params}: fitted for method {params_file['method']!r}, "
                         f"not {name!r}")
    method = methods.get(name)
    model = getattr(args, "model", None)
    if model is not None and method.load_model is None:
        takers = [m for m in methods.names() if methods.get(m).load_model is not None]
        raise InputError(f"--model {model}: only --method {' or '.join(takers)} takes a model, not {name!r}")
    options, base = None, None
    if method.load_model is not None:
        _, base = method.load_model(model)            # a bad model file fails here, before any output
        options = {"model": model}                    # loaded once per process (the loader caches it)
    given = {key: value for key, value in zip(_TILING_OPTIONS, tiling) if value is not None}
    tiling_ = _tiling(method, given) if given else None
    config, params = methods.make_config_and_params(
        method, parse_set_values(args.set_values), args.preset, values=params_file["values"] if params_file else None,
        values_source=f"--params {args.params}", base_config=base, tiling=tiling_,
        tiling_sources={key: _TILING_OPTIONS[key] for key in given})
    if tiling_ is not None:
        options = {**(options or {}), "tiling": tiling_}
    fixed = None
    if args.preset != adaptive.FIXED_PRESET:
        fixed = frozenset(parse_set_values(args.set_values)) | frozenset(params_file["values"] if params_file else ())
        fixed |= frozenset(method.presets.get(args.preset, {}))
    return MethodSetup(method, config, params, options, fixed)


_TILING_OPTIONS = {"tile_size_m": "--tile-size", "buffer_m": "--buffer"}


def _tiling(method: Method, given: dict[str, float]):
    """The `gfjax.Tiling` of `--tile-size` / `--buffer` (`given`: their fields), range-checked;
    against the method's cell and the memory budget by `make_config_and_params`."""
    from gfjax.tiling.tiles import Tiling

    if not method.tiles:
        raise InputError(f"{_TILING_OPTIONS[next(iter(given))]}: method {method.name} does not tile")
    try:
        return Tiling(**given)
    except ValueError as err:
        raise InputError(f"{_TILING_OPTIONS[err.keys[0]]}: {err}") from None


def add_neighbours_option(parser: argparse.ArgumentParser) -> None:
    """`--buffer M`: with several inputs, the ground of the neighbour files within M metres of
    each file enters its TIN (`gfjax hag`, `gfjax dtm`), so heights and rasters agree across
    file borders."""
    parser.add_argument("--buffer", type=nonnegative_float, default=NEIGHBOURS_GROUND_M, metavar="M",
                        help=f"neighbour files' ground around each file [m] (default {NEIGHBOURS_GROUND_M:g})")


def neighbours_ground(inputs: Sequence[Path], args: argparse.Namespace):
    """With several inputs and a `--buffer`, a catalog of the survey (`gfjax.survey.index`) in a
    scratch folder, and `around(i, xyz_m) -> (k, 3)` [m]: the other files' ground (class
    `args.ground_class`) within the buffer of file `i`'s points; else `(None, None)`.

    Returns:
      `(folder, around)`: the scratch folder to clean up (or None), and `around` (or None).
    """
    if len(inputs) < 2 or args.buffer <= 0:
        return None, None
    from gfjax import survey
    from gfjax.io import atomic
    from gfjax.survey import halo

    folder = atomic.scratch_folder()
    catalog = survey.index(inputs, folder.name, units=args.units)

    def around(i: int, xyz_m):
        return halo.classified_ground_near(catalog, i, xyz_m, args.buffer, args.ground_class)

    return folder, around


def output_targets(inputs: Sequence[Path], output: str, *, option: str = "-o",
                   suffixes: tuple[str, ...] | None = None, rename_suffix: str | None = None) -> list[Path]:
    """One output path per input: `output` itself for one input, else `output/<input name>`.

    `output` is taken as a folder when there are several inputs or when it is an existing
    folder; the folder must exist. `rename_suffix` replaces the inputs' suffix (".tif" for
    DTMs). Two inputs of the same name would overwrite each other: refused.
    """
    if output == "":
        raise InputError(f"{option} '': empty output name")
    out = Path(output)
    try:
        is_dir = out.is_dir()
    except OSError as err:  # a name too long, a loop of links
        raise InputError(f"{option} {out}: cannot write ({err.strerror or err})") from None
    if len(inputs) > 1 or is_dir:
        if not out.is_dir():
            raise InputError(f"{option} {out}: {len(inputs)} inputs need an existing output folder")
        targets = [out / (p.with_suffix(rename_suffix).name if rename_suffix else p.name) for p in inputs]
    else:
        targets = [out]
    seen: dict[str, Path] = {}
    for source, target in zip(inputs, targets):
        key = os.path.realpath(target)
        if key in seen:
            raise InputError(f"{option} {target}: inputs {seen[key]} and {source} would both write it")
        seen[key] = source
    if suffixes is not None:
        for target in targets:
            if target.suffix.lower() not in suffixes:
                raise InputError(f"{option} {target}: output must end in {' or '.join(suffixes)}")
    return targets
