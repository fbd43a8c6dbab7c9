"""`gfjax cache [info|clear]`: where compiled programs are kept, how much they take, and
emptying them.

Two caches (`gfjax.cache`): JAX's persistent compilation cache and gfjax's store of compiled
programs. Each has a bound (JAX's: 1 GiB, least recently used first, when the `filelock`
package is installed; the program store: 512 programs or 256 MiB), so neither grows without
end; `clear` empties both (the next run of each input shape compiles again, and keeps it).
Only the caches' own files directly in their folders are touched: no link is followed, no
sub-folder entered.
"""
from __future__ import annotations

import argparse
import os
import stat
from pathlib import Path

ACTIONS = ("info", "clear")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("cache", help="size of the program caches, or empty them",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("action", nargs="?", choices=ACTIONS, default="info",
                        help="info: folders, entries and sizes (default); clear: remove every entry")
    return parser


def _folders() -> list[tuple[str, Path | None, str]]:
    """`(name, folder or None when off, bound)` of each cache, as this process would use them."""
    from gfjax import aot, cache

    off = os.environ.get(cache.SWITCH_ENV, "1") in ("", "0")
    jax_setting = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    jax_folder = None if off or jax_setting == "" or (jax_setting and "://" in jax_setting) else \
        Path(jax_setting or cache.folder())
    program_folder = None if off else cache.export_folder()
    return [("JAX compilation cache", jax_folder, f"{cache.CACHE_SIZE_BYTES / 2**30:g} GiB"),
            ("gfjax program store", program_folder,
             f"{aot.MAX_FILES} programs or {aot.MAX_BYTES / 2**20:g} MiB")]


def entries(folder: Path) -> list[os.DirEntry]:
    """The regular files directly in `folder` (none when it does not exist); links and
    sub-folders are left out."""
    try:
        with os.scandir(folder) as found:
            return [e for e in found if stat.S_ISREG(e.stat(follow_symlinks=False).st_mode)]
    except (FileNotFoundError, NotADirectoryError):
        return []


def run(args: argparse.Namespace) -> int:
    for name, folder, bound in _folders():
        if folder is None:
            print(f"{name}: off")
            continue
        files = entries(folder)
        size = sum(e.stat(follow_symlinks=False).st_size for e in files)
        if args.action == "clear":
            for entry in files:
                try:
                    os.unlink(entry.path)
                except FileNotFoundError:                # removed by another process meanwhile
                    pass
                except OSError as err:
                    from gfjax.errors import InputError

                    raise InputError(f"{entry.path}: cannot remove ({err.strerror or err})") from None
            print(f"{name}: {folder}: removed {len(files)} files, {size / 2**20:.1f} MiB")
        else:
            print(f"{name}: {folder}: {len(files)} files, {size / 2**20:.1f} MiB (bound: {bound})")
    return 0
