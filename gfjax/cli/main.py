"""`gfjax` command line: one entry point, one module per subcommand (SPEC section 2).

Each subcommand lives in `gfjax.cli.<name>` and provides

- `add_parser(subparsers) -> argparse.ArgumentParser`: registers `<name>` and its options;
- `run(args) -> int`: does the work; raises `InputError` for bad input;
- optionally `ANNOUNCE_COMPILES = False`: no "compiling" line on stderr (compiling is its work).

Only the module of the command being run is imported (subcommand modules keep heavy imports
such as JAX inside `run`). Modules of `SUBCOMMANDS` that are not installed are left out,
except `demo`, which then says it is not available.

Exit codes: 0 success; 2 bad input or option, printed as one line
`gfjax: error: <file or option>: <problem>` (no traceback, no output file left behind);
1 internal error, with the traceback only under `--debug` or `GFJAX_DEBUG=1`; 128 + the
signal number when interrupted: Ctrl-C (130), SIGTERM (143) and SIGHUP (129) are all handled
alike, as an exception in the main thread, so every temporary file is removed on the way out
and one line `gfjax: interrupted by SIG...` is printed. When the reader of the output goes
away (`gfjax info f.laz | head -1`) the command ends quietly with 141, 128 + SIGPIPE, as GNU
tools and PDAL do (`_closed_output`).
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import logging
import os
import select
import signal
import sys
import threading
import traceback
from collections.abc import Sequence
from types import ModuleType
from typing import NoReturn

from gfjax import aot, cache, heap
from gfjax.errors import InputError

# Subcommand module names, in help order, with their one-line help (shown without importing).
SUBCOMMANDS: dict[str, str] = {
    "info": "header, CRS, units and class counts of LAS/LAZ files",
    "filter": "classify ground points, write LAS/LAZ (and a DTM)",
    "dtm": "build a DTM GeoTIFF from a file's ground points (class 2)",
    "hag": "height above ground of every point (HeightAboveGround), or heights as z",
    "eval": "score ground labels against reference labels",
    "tune": "fit a method's thresholds against labelled files",
    "train": "train the SparseGF model",
    "bench": "compare the speed and accuracy of methods and peers",
    "demo": "filter the embedded sample (no arguments, no network)",
    "warmup": "compile the methods' programs ahead, so first runs start at once",
    "cache": "size of the program caches, or empty them",
}
ALWAYS_LISTED = ("demo",)


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are `InputError`s (one line, exit code 2).

    Its `epilog` may be a callable returning the text: it is called only when the help is
    printed, so a help text that must import the method packages (their presets) costs
    nothing to the commands that merely parse their options.
    """

    def format_help(self) -> str:
        if callable(self.epilog):
            self.epilog = self.epilog()
        return super().format_help()

    def error(self, message: str):
        message = message.removeprefix("argument ")
        if message.startswith("the following arguments are required"):
            message = f"{self.prog}: {message}"
        raise InputError(message)


def _module_present(name: str) -> bool:
    return importlib.util.find_spec(f"gfjax.cli.{name}") is not None


def _import_command(name: str) -> ModuleType | None:
    try:
        return importlib.import_module(f"gfjax.cli.{name}")
    except ModuleNotFoundError as err:
        if err.name == f"gfjax.cli.{name}":
            return None
        raise


def _requested_command(argv: Sequence[str]) -> str | None:
    for arg in argv:
        if not arg.startswith("-"):
            return arg
    return None


def build_parser(argv: Sequence[str]) -> tuple[argparse.ArgumentParser, ModuleType | None]:
    """The parser, with full options for the requested command; and that command's module."""
    from gfjax import __version__

    parser = _Parser(prog="gfjax", description="Ground filtering of airborne LiDAR point clouds (JAX).")
    parser.add_argument("--version", action="version", version=f"gfjax {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars and no compile notices")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    requested = _requested_command(argv)
    module = None
    for name, summary in SUBCOMMANDS.items():
        if name == requested:
            module = _import_command(name)
        if name == requested and module is not None:
            sub = module.add_parser(subparsers) or subparsers.choices[name]
            if not any("--debug" in action.option_strings for action in sub._actions):
                sub.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                                 help="show tracebacks of errors")
            if not any("--quiet" in action.option_strings for action in sub._actions):
                sub.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                                 help="no progress bars and no compile notices")
        elif name in ALWAYS_LISTED or _module_present(name):
            subparsers.add_parser(name, help=summary, description=summary)
    return parser, module


def _refuse_empty_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """An empty string given as a file name or value (`-o ''`, an input `''`) is an error: as a
    path it would mean the current folder, and as an option it would silently count as unset."""
    actions = list(parser._actions)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and args.command in action.choices:
            actions += action.choices[args.command]._actions
    for action in actions:
        value = getattr(args, action.dest, None)
        if value == "" or (isinstance(value, list) and "" in value):
            label = action.option_strings[0] if action.option_strings else (action.metavar or action.dest)
            raise InputError(f"{label}: empty argument ''")


def _method_of(args: argparse.Namespace) -> str | None:
    """The one method a command runs, if it names one (`filter` without `--method`: the default)."""
    method = getattr(args, "method", None)
    if method is None and args.command == "filter":
        from gfjax.methods import DEFAULT_METHOD

        return DEFAULT_METHOD
    return method if isinstance(method, str) else None


@contextlib.contextmanager
def _talk(*, quiet: bool, method: str | None, notice: bool = True):
    """While a command runs: say once on stderr when it must compile (a first run of a new
    input shape sits silent for seconds otherwise), or, `quiet`, no such line and no progress
    bars (tqdm reads `TQDM_DISABLE` when first imported; the commands import it late).
    `notice=False`: no such line (a command whose work is compiling)."""
    said = []

    def say(module: str) -> None:
        if said:
            return
        said.append(module)
        from gfjax.methods import PACKAGES

        what = next((name for name, package in PACKAGES.items() if module == package or
                     module.startswith(f"{package}.")), method or "")
        what = f"{what} " if what else ""
        line = f"gfjax: compiling {what}for a new input shape (kept, so later runs of this shape start at once)"
        if "tqdm" in sys.modules:                       # between progress bars, not through one
            sys.modules["tqdm"].tqdm.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)

    before = os.environ.get("TQDM_DISABLE")
    if quiet:
        os.environ["TQDM_DISABLE"] = "1"
    elif notice:
        aot.on_compile(say)
    try:
        yield
    finally:
        aot.on_compile(None)
        if quiet and before is None:
            os.environ.pop("TQDM_DISABLE", None)
        elif quiet:
            os.environ["TQDM_DISABLE"] = before


HANDLED_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
# The signal that arrived during this run, if any: a library that calls back into Python (lazrs
# writing LAZ) may turn the `Interrupted` raised in its callback into an error of its own.
_arrived: dict[str, int] = {}


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP, raised in the main thread as a KeyboardInterrupt, so the
    same `finally` blocks remove temporary files (`gfjax.io.atomic`)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_interrupted(signum, frame) -> None:
    _arrived.setdefault("signum", signum)
    for sig in HANDLED_SIGNALS:                 # a second signal must not cut the clean-up short
        with contextlib.suppress(ValueError, OSError):
            signal.signal(sig, signal.SIG_IGN)
    raise Interrupted(signum)


@contextlib.contextmanager
def _signals_interrupt():
    """While the command runs, SIGINT, SIGTERM and SIGHUP raise `Interrupted` (main thread
    only); the previous handlers come back afterwards."""
    _arrived.clear()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in HANDLED_SIGNALS:
            with contextlib.suppress(ValueError, OSError):
                previous[sig] = signal.signal(sig, _raise_interrupted)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            with contextlib.suppress(ValueError, OSError):
                signal.signal(sig, handler)


def _one_line(message: object) -> str:
    return " ".join(str(message).split())


def _reader_gone(stream) -> bool:
    """True when `stream` is a pipe or socket whose reading end is closed (poll reports an
    error on its writing end); False when it is not, or cannot tell (no file descriptor)."""
    try:
        poller = select.poll()
        poller.register(stream.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return False


def _closed_output() -> int:
    """The exit code when a write met a closed pipe (`BrokenPipeError`): 128 + SIGPIPE.

    GNU tools and PDAL do not catch SIGPIPE: the kernel ends them at the first write to a pipe
    nobody reads, silently, and the shell reports 141. Python ignores SIGPIPE, so the write
    raises instead; this ends the command the same way: no message, exit code 141 (what
    `set -o pipefail` scripts expect of `cmd | head`). A stream whose reader is gone is pointed
    at /dev/null, so that flushing what it still buffers cannot raise again at exit.
    """
    for stream in (sys.stdout, sys.stderr):
        if _reader_gone(stream):
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, stream.fileno())
            finally:
                os.close(devnull)
    return 128 + int(signal.SIGPIPE)


def _end_process(code: int) -> NoReturn:
    """Exit at once with `code`, skipping the interpreter's teardown.

    Tearing down a process that imported JAX frees every module and XLA object one by one:
    0.25 s after `import jax` alone, 0.4 s after `gfjax filter --method dmf` on bcts_2 (measured
    by `experiments/dmf_speed.py`, "process exit"), a third of the whole command. Every output
    is already written, flushed and renamed into place (`gfjax.io.atomic`); the standard
    streams and logging are flushed here.
    """
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def main(argv: Sequence[str] | None = None) -> int:
    """Run `gfjax` with `argv` and return the exit code.

    Without `argv` (the `gfjax` program: `sys.argv[1:]`) the process ends here with that code,
    skipping the interpreter's teardown (`_end_process`), and its heap is set for large
    windows (`gfjax.heap.tune`); with `argv` (tests, other Python code) the code is
    returned and the process's allocator is left as it is.
    """
    if argv is None:
        heap.tune()
        _end_process(_run(sys.argv[1:]))
    return _run(argv)


def _run(argv: Sequence[str]) -> int:
    argv = list(argv)
    debug = "--debug" in argv or os.environ.get("GFJAX_DEBUG", "") not in ("", "0")
    try:
        with _signals_interrupt():
            parser, module = build_parser(argv)
            args = parser.parse_args(argv)
            _refuse_empty_arguments(parser, args)
            if module is None:
                raise InputError(f"{args.command}: not available in this build")
            cache.setup()
            with _talk(quiet=args.quiet, method=_method_of(args), notice=getattr(module, "ANNOUNCE_COMPILES", True)):
                code = int(module.run(args) or 0)
            sys.stdout.flush()              # a closed pipe is found here, not at exit
            return code
    except BrokenPipeError:
        return _closed_output()
    except InputError as err:
        if debug:
            traceback.print_exc()
        print(f"gfjax: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except SystemExit as exit_:  # --help, --version
        return exit_.code if isinstance(exit_.code, int) else 0
    except KeyboardInterrupt as err:
        signum = getattr(err, "signum", signal.SIGINT)
        print(f"gfjax: interrupted by {signal.Signals(signum).name}; no partial output left", file=sys.stderr)
        return 128 + int(signum)
    except Exception as err:  # noqa: BLE001 (the one place that turns bugs into exit code 1)
        if "signum" in _arrived:        # the interruption, wrapped by a library on its way out
            signum = _arrived["signum"]
            print(f"gfjax: interrupted by {signal.Signals(signum).name}; no partial output left", file=sys.stderr)
            return 128 + int(signum)
        if debug:
            traceback.print_exc()
        print(f"gfjax: internal error: {type(err).__name__}: {_one_line(err)} "
              "(run with --debug or GFJAX_DEBUG=1 for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
