"""Atomic output files: checked before any work, written to a temporary file beside the
target, fsynced and renamed onto it, so a failed run never leaves a partial or stale file.

Used by every writer of gfjax (LAS/LAZ, GeoTIFF, PNG, params.json).

Temporary files are named `.<target name>.gfjax-tmp-<host>-<pid>-<8 hex>`: hidden, and with
no `.las`/`.laz`/`.tif` suffix, so no folder or glob input of a later run picks one up
(`gfjax.io.las.expand_inputs` also skips them by name). The writer removes its temporary on
any error, Ctrl-C, SIGTERM or SIGHUP (`gfjax.cli.main`). A temporary left by a process that
could not clean up (SIGKILL, power loss) is *stale*, and the next write into that folder
removes it, when it is ours (same user) and either its process is gone (same host, pid no
longer running) or it has not been modified for `STALE_AGE_S` (24 hours; a temporary from
another host, whose pid cannot be checked, is only removed by age).
"""
from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import shutil
import socket
import stat
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

from gfjax.errors import InputError

TMP_MARK = ".gfjax-tmp-"
STALE_AGE_S = 24 * 3600.0
_TMP_NAME = re.compile(r"^\..+\.gfjax-tmp-(?P<host>.+)-(?P<pid>\d+)-[0-9a-f]{8}$")
# Temporaries of gfjax <= 0.x: `.<stem>.<8 hex>.tmp<suffix>` (they ended in the target's suffix).
_OLD_TMP_NAME = re.compile(r"^\..+\.[0-9a-f]{8}\.tmp(\.[A-Za-z0-9]+)?$")
_NAME_KEEP = 100            # characters of the target name kept in a temporary name (NAME_MAX 255)


def _host() -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", socket.gethostname())[:32] or "host"


def temporary_name(out: Path) -> Path:
    """A fresh temporary path beside `out` (see the module docstring for the pattern)."""
    return out.with_name(f".{out.name[:_NAME_KEEP]}{TMP_MARK}{_host()}-{os.getpid()}-{secrets.token_hex(4)}")


def is_temporary(path: str | os.PathLike) -> bool:
    """True for a name of a gfjax temporary file (this version's pattern or the older one)."""
    name = Path(path).name
    return bool(_TMP_NAME.match(name) or _OLD_TMP_NAME.match(name))


def _pid_running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True
    return True


def is_stale(path: str | os.PathLike, *, now: float | None = None) -> bool:
    """True when `path` is a gfjax temporary of this user whose writer is gone: same host and
    its pid is not running, or not modified for `STALE_AGE_S`. False for anything else."""
    path = Path(path)
    name = path.name
    match = _TMP_NAME.match(name)
    if match is None and not _OLD_TMP_NAME.match(name):
        return False
    try:
        info = os.lstat(path)
    except OSError:
        return False
    if info.st_uid != os.getuid() or not os.path.isfile(path) or os.path.islink(path):
        return False
    now = time.time() if now is None else now
    if now - info.st_mtime > STALE_AGE_S:
        return True
    if match is None or match["host"] != _host():
        return False
    pid = int(match["pid"])
    return pid != os.getpid() and not _pid_running(pid)


SCRATCH_PREFIX = "gfjax-survey-"
_SCRATCH_NAME = re.compile(r"^gfjax-survey-(?P<host>[A-Za-z0-9_]+)-(?P<pid>\d+)-[A-Za-z0-9_]+$")


def scratch_folder() -> tempfile.TemporaryDirectory:
    """A private working folder in `$TMPDIR` (a survey's stores), named for this host and
    process, removed on the way out like any temporary; first, the folders of earlier runs
    that were killed (SIGKILL, power loss) are removed: this user's, whose process is gone
    (same host) or that were not modified for `STALE_AGE_S`."""
    remove_stale_scratch(tempfile.gettempdir())
    return tempfile.TemporaryDirectory(prefix=f"{SCRATCH_PREFIX}{_host()}-{os.getpid()}-",
                                       ignore_cleanup_errors=True)


def remove_stale_scratch(folder: str | os.PathLike, *, now: float | None = None) -> list[Path]:
    """Remove the working folders of killed runs (`scratch_folder`) directly inside `folder`;
    returns them. A link, another user's folder or anything not named so is left alone."""
    removed = []
    now = time.time() if now is None else now
    try:
        entries = [e for e in os.scandir(folder) if e.name.startswith(SCRATCH_PREFIX)]
    except OSError:
        return removed
    for entry in entries:
        match = _SCRATCH_NAME.match(entry.name)
        try:
            info = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        if match is None or not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid():
            continue
        old = now - info.st_mtime > STALE_AGE_S
        gone = match["host"] == _host() and int(match["pid"]) != os.getpid() and not _pid_running(int(match["pid"]))
        if old or gone:
            shutil.rmtree(entry.path, ignore_errors=True)
            removed.append(Path(entry.path))
    return removed


def remove_stale_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Remove the stale gfjax temporaries (`is_stale`) directly inside `folder`; returns them.
    Errors (a folder that cannot be listed, a file removed meanwhile) are ignored."""
    removed = []
    try:
        names = [entry.name for entry in os.scandir(folder) if TMP_MARK in entry.name or ".tmp" in entry.name]
    except OSError:
        return removed
    for name in names:
        path = Path(folder) / name
        if is_stale(path):
            with contextlib.suppress(OSError):
                path.unlink()
                removed.append(path)
    return removed


def _same_file(a: Path, b: Path) -> bool:
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_output(path: str | os.PathLike, *, force: bool = False,
                 input_paths: Iterable[str | os.PathLike] = (),
                 suffixes: tuple[str, ...] | None = None, option: str = "",
                 refuse_existing: bool = False) -> Path:
    """Check that `path` can be written, before any work is done; returns it as a `Path`.

    `refuse_existing` applies the command line's rule: an existing file is not overwritten
    unless `force` (`--force`). The Python API replaces an existing file, as `open(path, "w")`.

    Raises:
      InputError: an empty name, a name the system refuses (too long), a wrong suffix, a folder
        that does not exist / is not a folder / is not writable, `path` is a folder, `path` is
        one of `input_paths` and not `force`, or `path` exists, `refuse_existing` and not `force`.
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
    if refuse_existing and not force and os.path.lexists(out):
        raise InputError(existing_output_message(where))
    return out


def existing_output_message(where: str, *, more: int = 0) -> str:
    """The one line that refuses an existing output, `where` naming it ("-o out.laz"), with
    `more` other existing outputs of the same run counted."""
    if more:
        return f"{where}: exists, and {more} more of the outputs; pass --force to overwrite them"
    return f"{where}: exists; pass --force to overwrite it"


def _publish(tmp: Path, out: Path, *, exclusive: bool) -> None:
    """Give the written temporary `tmp` the name `out`: replacing whatever is there, or with
    `exclusive` only while no file has that name. The exclusive move is a hard link, which the
    system refuses on an existing name, then the temporary's name removed: of two writers of
    one new output, one succeeds and the other is told (a check before the work cannot tell,
    since both pass it). Where the file system has no hard links, an `O_EXCL` claim of the name
    and then the rename."""
    if not exclusive:
        os.replace(tmp, out)
        return
    try:
        os.link(tmp, out)
    except FileExistsError:
        raise InputError(existing_output_message(str(out)) + " (written by another process meanwhile)") from None
    except OSError as err:
        if err.errno not in _NO_LINKS:
            raise
        try:
            os.close(os.open(out, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            raise InputError(existing_output_message(str(out)) + " (written by another process meanwhile)") from None
        os.replace(tmp, out)
        return
    os.unlink(tmp)


# errno values of a file system that makes no hard links (FAT, some network and FUSE mounts)
_NO_LINKS = {errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK, errno.ENOSYS}


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, *, force: bool = False,
                  input_paths: Iterable[str | os.PathLike] = (),
                  suffixes: tuple[str, ...] | None = None, option: str = "",
                  staged: Path | None = None, exclusive: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success fsync it and rename it onto `path`
    (with `exclusive`, only if no file has that name by then: `_publish`; the command line's
    rule without `--force`).

    The temporary file (`temporary_name`: hidden, same folder, no input suffix, mode 0666 less
    the umask) is removed if the body raises or the process is interrupted, so a failed write
    leaves no file behind; stale temporaries of killed runs in the folder are removed first
    (`remove_stale_temporaries`). Writers must name the format explicitly (the temporary has
    no suffix to guess it from). Checks as `check_output`.

    With `staged`, a temporary name beside `path` (`temporary_name`, made by the process that
    will commit it, so its own sweep never takes it for stale while it lives), the file is
    written there and left there on success, for that process to `commit` or remove.
    """
    out = check_output(path, force=force, input_paths=input_paths, suffixes=suffixes, option=option)
    remove_stale_temporaries(out.absolute().parent)
    tmp = temporary_name(out) if staged is None else Path(staged)
    kept = False
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        os.close(fd)
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        if staged is not None:
            kept = True
            return
        _publish(tmp, out, exclusive=exclusive)
    except OSError as err:
        raise InputError(f"{out}: cannot write ({err.strerror or err})") from None
    finally:
        if not kept:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
    _sync_folder(out)


def commit(tmp: str | os.PathLike, path: str | os.PathLike, *, exclusive: bool = False) -> None:
    """Rename a staged temporary (`atomic_output(..., staged=...)`) onto `path`, durably (with
    `exclusive`, only while no file has that name: `_publish`; the temporary is then removed)."""
    try:
        try:
            _publish(Path(tmp), Path(path), exclusive=exclusive)
        except InputError:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            raise
    except OSError as err:
        raise InputError(f"{path}: cannot write ({err.strerror or err})") from None
    _sync_folder(Path(path))


def _sync_folder(out: Path) -> None:
    with contextlib.suppress(OSError):  # make the rename durable; not every file system can
        dir_fd = os.open(out.absolute().parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


__all__ = ["atomic_output", "check_output", "commit", "existing_output_message", "temporary_name", "is_temporary", "is_stale",
           "remove_stale_temporaries", "STALE_AGE_S"]
