"""The store's folder and each file in it, checked before a byte is read.

The files hold pickled pytree definitions next to machine code, so nothing another user could
have written is ever loaded. The folder must be private: owned by this user, mode 0700
(`private_folder` creates it so, and tightens a folder of ours that others can only read), and
every folder above it owned by root or this user and writable by no one else (unless sticky, as
`/tmp`). That is checked again each time a program is looked up, not only at `enable`: the path
is walked from `/` one folder at a time with `O_NOFOLLOW` (`open_folder`: a folder swapped for a
symbolic link is refused), and each file is opened relative to the checked folder's descriptor,
with `O_NOFOLLOW`, then checked on that descriptor (`check_file`: a regular file owned by this
user, writable by no one else) before a byte of it is unpickled. A refused folder or file means
plain compilation, with one warning line on stderr per process (`warn_once`).
"""
from __future__ import annotations

import errno
import os
import stat as stat_
import sys
from pathlib import Path

__all__ = ["Refused", "private_folder", "planted_entry", "warn_once", "open_folder", "check_file", "reason",
           "FILE_FLAGS", "MAX_ENTRY_BYTES"]

MAX_ENTRY_BYTES = 64 * 2**20          # a larger file is refused unread
_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
FILE_FLAGS = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NONBLOCK", 0)

_state = {"warned": False}            # one warning line per process, for every cache


class Refused(Exception):
    """A folder or file another user could have written (the message says why)."""


def private_folder(folder: str | os.PathLike, *, what: str = "program cache") -> Path | None:
    """`folder`, created with mode 0700 if needed, symbolic links resolved, if it is private to
    this user: owned by this user with no group or other permission (a folder of ours that
    others may only read or enter is tightened to 0700), and every folder above it owned by
    root or this user and writable by no one else unless sticky. Otherwise None, and one
    warning line on stderr (once per process) says why and that `what` stays off.

    The same rule serves JAX's persistent compilation cache (`gfjax.cli.main`): its entries
    are executables, so a folder someone else can write is no cache."""
    path = Path(folder).expanduser()
    try:
        if not _supported():
            raise Refused("this system cannot open files relative to a folder (no O_NOFOLLOW, dir_fd)")
        os.makedirs(path, mode=0o700, exist_ok=True)
        path = Path(os.path.realpath(path))
        fd = open_folder(path, tighten=True)
        os.close(fd)
    except (Refused, OSError) as err:
        warn_once(f"{reason(err, folder)}; running without the {what}")
        return None
    return path


def planted_entry(folder: str | os.PathLike) -> str | None:
    """The first entry of the cache folder `folder` that this user's processes did not write: one
    owned by another user, or a symbolic link (JAX's cache entries are plain files); None when
    there is none. `private_folder` keeps others from writing there, but root, or this user
    under `sudo`, may have; JAX loads whatever executable it finds under a matching name, so
    `gfjax.cache.enable` refuses a folder with such an entry. About 4 ms for 1,300 entries.
    A description of the entry, for the warning."""
    uid = os.getuid()
    try:
        names = os.listdir(folder)
    except OSError as err:
        return f"{folder}: {err.strerror or err}"
    for name in names:
        path = os.path.join(folder, name)
        try:
            info = os.lstat(path)
        except FileNotFoundError:                       # evicted by another process meanwhile
            continue
        if stat_.S_ISLNK(info.st_mode):
            return f"{path}: a symbolic link"
        if info.st_uid != uid:
            return f"{path} is owned by user {info.st_uid}"
    return None


def warn_once(message: str) -> None:
    """One line on stderr, the first time a cache is refused in this process (the program
    store's or, through `gfjax.cache`, JAX's): one line in all."""
    if not _state["warned"]:
        _state["warned"] = True
        print(f"gfjax: warning: {message}", file=sys.stderr)


def _supported() -> bool:
    return (hasattr(os, "O_NOFOLLOW") and hasattr(os, "getuid") and os.open in os.supports_dir_fd
            and os.unlink in os.supports_dir_fd and os.rename in os.supports_dir_fd
            and os.scandir in os.supports_fd)


def reason(err: Exception, folder) -> str:
    """One line: what is wrong with `folder` or a folder above it."""
    if isinstance(err, OSError) and err.errno in (errno.ELOOP, errno.ENOTDIR):
        return f"{err.filename or folder}: a symbolic link or not a folder"
    if isinstance(err, OSError):
        return f"{err.filename or folder}: {err.strerror or err}"
    return str(err)


def open_folder(path: Path, *, tighten: bool = False) -> int:
    """A descriptor of the folder `path` (absolute, symbolic links resolved), opened one folder
    at a time from `/` with `O_NOFOLLOW`, each checked on its own descriptor (see
    `private_folder`). With `tighten`, the folder itself is set to 0700 when it is ours and
    others may only read it. Raises `Refused` or `OSError` (a symbolic link: `ELOOP`)."""
    uid = os.getuid()
    fd = os.open("/", _DIR_FLAGS)
    try:
        parts = path.parts[1:]
        _check_folder(fd, "/", uid, last=not parts, tighten=tighten)
        for depth, name in enumerate(parts, start=1):
            try:
                child = os.open(name, _DIR_FLAGS, dir_fd=fd)
            except OSError as err:
                err.filename = str(Path(*path.parts[:depth + 1]))
                raise
            os.close(fd)
            fd = child
            _check_folder(fd, Path(*path.parts[:depth + 1]), uid, last=depth == len(parts), tighten=tighten)
        return fd
    except BaseException:
        os.close(fd)
        raise


def _check_folder(fd: int, where, uid: int, *, last: bool, tighten: bool) -> None:
    info = os.fstat(fd)
    mode = stat_.S_IMODE(info.st_mode)
    if not stat_.S_ISDIR(info.st_mode):
        raise Refused(f"{where} is not a folder")
    if last:
        if info.st_uid != uid:
            raise Refused(f"{where} is owned by user {info.st_uid}, not by this user ({uid})")
        if mode & 0o022:
            raise Refused(f"{where} can be written by other users (mode {mode:04o}; it must be 0700)")
        if mode & 0o077 and tighten:                          # ours, others may only read: tighten
            os.fchmod(fd, 0o700)
        elif mode & 0o077:
            raise Refused(f"{where} is not private (mode {mode:04o}; it must be 0700)")
    else:
        if info.st_uid not in (0, uid):
            raise Refused(f"{where} is owned by user {info.st_uid}, neither root nor this user ({uid})")
        if mode & 0o022 and not mode & stat_.S_ISVTX:
            raise Refused(f"{where} can be written by other users (mode {mode:04o})")


def check_file(fd: int, name: str) -> os.stat_result:
    """The status of an opened cache file, if only this user could have written it."""
    info = os.fstat(fd)
    mode = stat_.S_IMODE(info.st_mode)
    if not stat_.S_ISREG(info.st_mode):
        raise Refused(f"{name} is not a regular file")
    if info.st_uid != os.getuid():
        raise Refused(f"{name} is owned by user {info.st_uid}, not by this user ({os.getuid()})")
    if mode & 0o022:
        raise Refused(f"{name} can be written by other users (mode {mode:04o})")
    if info.st_size > MAX_ENTRY_BYTES:
        raise Refused(f"{name} is larger than {MAX_ENTRY_BYTES} bytes")
    return info
