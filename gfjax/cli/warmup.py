"""`gfjax warmup`: compile each method's programs for every canonical input shape, ahead.

A method that pads its rasters and point arrays to a few canonical shapes
(`gfjax.tiling.buckets.canonical_sides`) runs the same handful of programs on every file; this
command loads or compiles them into the program cache (`~/.cache/gfjax`), so the first
`gfjax filter` of a new file starts at once. `make demo` runs it for SMRF; run it again after
upgrading gfjax or JAX (the cached programs are keyed to both). Methods without canonical
shapes compile on their first run of each new input size, as before.
"""
from __future__ import annotations

import argparse
import time

from gfjax.errors import InputError

ANNOUNCE_COMPILES = False      # every program it meets is compiled: no line per new shape


def add_parser(subparsers) -> argparse.ArgumentParser:
    from gfjax.methods import names

    parser = subparsers.add_parser("warmup", help="compile the methods' programs ahead, so first runs start at once",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--methods", nargs="+", choices=names(), metavar="METHOD",
                        help="methods to prepare (default: every method with canonical shapes)")
    return parser


def warmable() -> list[str]:
    """The methods with canonical input shapes to prepare (`Method.warm`)."""
    from gfjax import methods

    return [name for name in methods.available() if methods.get(name).warm is not None]


def run(args: argparse.Namespace) -> int:
    from gfjax import aot, methods

    names = args.methods or warmable()
    folder = aot.enabled_folder()
    if folder is None:
        raise InputError("warmup: the program cache is off (GFJAX_CACHE=0, GFJAX_EXPORT_CACHE=0 or a refused "
                         "folder), so nothing compiled now would be kept")
    chosen = {name: methods.get(name) for name in names}
    for name, method in chosen.items():
        if method.warm is None:
            raise InputError(f"--methods: {name} has no canonical shapes to prepare; it compiles on first use "
                             f"(choose from {', '.join(warmable())})")
    for name, method in chosen.items():
        start = time.perf_counter()
        shapes = method.warm(progress=True)
        print(f"{name}: {shapes} input shapes ready ({time.perf_counter() - start:.0f} s)", flush=True)
    print(f"programs kept in {folder}")
    return 0
