"""Atomic output files: checked before any work, written to a temporary file beside the
target, fsynced and renamed onto it, so a failed run never leaves a partial or stale file.

Used by every writer of gfjax (LAS/LAZ, GeoTIFF, PNG, params.json).
"""
from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterable, Iterator
from pathlib import Path

from gfjax.errors import InputError


def _same_file(a: Path, b: Path) -> bool:
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_output(path: str | os.PathLike, *, force: bool = False,
                 input_paths: Iterable[str | os.PathLike] = (),
                 suffixes: tuple[str, ...] | None = None, option: str = "") -> Path:
    """Check that `path` can be written, before any work is done; returns it as a `Path`.

    Raises:
      InputError: an empty name, a name the system refuses (too long), a wrong suffix, a folder that does not exist / is not a folder / is not
        writable, `path` is a folder, or `path` is one of `input_paths` and not `force`.
    """
    if os.fspath(path) == "":
        raise InputError(f"{option + ' ' if option else ''}'': empty output name")
    out = Path(path)
    where = f"{option} {out}" if option else str(out)
    try:
        os.stat(out)
    except (FileNotFoundError, NotADirectoryError):
        pass
    except OSError as err:  # a name too long, a loop of links
        raise InputError(f"{where}: cannot write ({err.strerror or err})") from None
    if suffixes is not None and out.suffix.lower() not in suffixes:
        raise InputError(f"{where}: output must end in {' or '.join(suffixes)}")
    folder = out.absolute().parent
    if not folder.exists():
        raise InputError(f"{where}: output folder {folder} does not exist")
    if not folder.is_dir():
        raise InputError(f"{where}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"{where}: output folder {folder} is not writable")
    if out.is_dir():
        raise InputError(f"{where}: is a folder, expected a file name")
    if not force and any(_same_file(out, Path(p)) for p in input_paths):
        raise InputError(f"{where}: is an input file; pass --force to overwrite it")
    return out


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, *, force: bool = False,
                  input_paths: Iterable[str | os.PathLike] = (),
                  suffixes: tuple[str, ...] | None = None, option: str = "") -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success fsync it and rename it onto `path`.

    The temporary file (hidden, same folder, same suffix, mode 0666 less the umask) is removed
    if the body raises, so a failed write leaves no file behind. Checks as `check_output`.
    """
    out = check_output(path, force=force, input_paths=input_paths, suffixes=suffixes, option=option)
    tmp = out.with_name(f".{out.stem}.{secrets.token_hex(4)}.tmp{out.suffix}")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        os.close(fd)
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, out)
    except OSError as err:
        raise InputError(f"{out}: cannot write ({err.strerror or err})") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    with contextlib.suppress(OSError):  # make the rename durable; not every file system can
        dir_fd = os.open(out.absolute().parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


__all__ = ["atomic_output", "check_output"]
