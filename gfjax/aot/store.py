"""The entries of the store: read, checked, unpickled, written and pruned.

One program is one file in the checked folder (`gfjax.aot.folder`), named by its key
(`gfjax.aot.keys`): `<key>.gfjaxexe` a serialized executable
(`jax.experimental.serialize_executable`), `<key>.export.gfjaxexe` exported StableHLO (a program
with XLA custom calls), `<key>.plain.gfjaxexe` an empty marker (a program that cannot be stored:
run it through plain jit). An entry carries its key and the SHA-256 of its contents: a file
swapped for another entry, truncated or stale is compiled again and replaced. Writes are atomic;
a write that fails (disk full) stores nothing this time and leaves no marker. The least recently
used entries beyond `MAX_FILES` or `MAX_BYTES` are removed.
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import pickle
import secrets
import stat as stat_
import time

from gfjax import heap
from gfjax.aot import folder

__all__ = ["MAX_FILES", "MAX_BYTES", "SUFFIX", "EXPORT_SUFFIX", "PLAIN_SUFFIX", "MAGIC", "read_entry", "wrap",
           "load", "load_exported", "exported_program", "serialize", "tree_survives", "write", "marker_present",
           "write_marker"]

MAX_FILES = 512                 # artifacts kept (least recently used go first); each is ~0.1-2 MB
MAX_BYTES = 256 * 2**20         # ... and their total size
SUFFIX = ".gfjaxexe"
EXPORT_SUFFIX = ".export" + SUFFIX  # a program with custom calls: exported StableHLO
PLAIN_SUFFIX = ".plain" + SUFFIX    # marker: this program is not stored, run it through plain jit
MAGIC = b"gfjax-aot 1\n"            # an entry: magic, key, SHA-256 of the body, pickled body
_STALE_TMP_S = 3600.0               # temporaries older than this are left by killed processes


def read_entry(dir_fd: int, name: str, key: str):
    """The unpickled body of the entry `name` in the checked folder `dir_fd`, or None when it
    is absent, unreadable, or holds another key or a damaged body (compile again and replace
    it). A file another user could have written is refused before a byte of it is read (one
    warning line). A hit refreshes the file's time (least recently used files go first)."""
    try:
        fd = os.open(name, folder.FILE_FLAGS, dir_fd=dir_fd)
    except FileNotFoundError:
        return None
    except OSError as err:
        if err.errno == errno.ELOOP:
            folder.warn_once(f"program cache entry {name}: a symbolic link; compiling it again")
        return None
    try:
        try:
            info = folder.check_file(fd, name)
        except folder.Refused as err:
            folder.warn_once(f"program cache entry {err}; compiling it again")
            return None
        chunks, left = [], info.st_size + 1
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 24))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
        body = _unwrap(b"".join(chunks), key)
        if body is None:
            return None
        payload = pickle.loads(body)
        with contextlib.suppress(OSError):
            os.utime(fd)
        return payload
    except Exception:                                       # unreadable: compile again
        return None
    finally:
        os.close(fd)


def wrap(key: str, body: bytes) -> bytes:
    """The entry of `key` holding `body`: magic, key, SHA-256 of the body, the body."""
    return MAGIC + key.encode() + b"\n" + hashlib.sha256(body).hexdigest().encode() + b"\n" + body


def _unwrap(blob: bytes, key: str) -> bytes | None:
    """The body of an entry, if it is one for `key` and intact."""
    header = MAGIC + key.encode() + b"\n"
    if not blob.startswith(header):
        return None
    digest, sep, body = blob[len(header):].partition(b"\n")
    if not sep or digest != hashlib.sha256(body).hexdigest().encode():
        return None
    return body


def load(dir_fd: int, name: str, key: str):
    """The stored executable `name`, or None (absent, refused or stale: compile again)."""
    from jax.experimental import serialize_executable

    payload = read_entry(dir_fd, name, key)
    if payload is None:
        return None
    try:
        return serialize_executable.deserialize_and_load(*payload)
    except Exception:
        return None
    finally:
        if len(payload[0]) >= TRIM_AFTER_BYTES:
            _return_scratch()


# Executables at least this large (serialized) give their load's scratch memory back
TRIM_AFTER_BYTES = 2**20


def _return_scratch() -> None:
    """Give the heap's free pages back to the system (`gfjax.heap.trim`).

    Loading an executable allocates about as much scratch memory as the program keeps and
    frees it again, and glibc keeps those pages: SparseGF's network (525 kernels, 3.4 MB)
    grows the heap by about 100 MB, half of it freed. Without this a 30-point file's process
    peaked at 380 MB (SparseGF) and 277 MB (SMRF), with it at 362 and 267 MB. A trim walks the
    heap, so only large programs' loads (`TRIM_AFTER_BYTES`: a method's few costly programs)
    are followed by one."""
    heap.trim()


def load_exported(dir_fd: int, name: str, key: str):
    """The exported program `name`, or None (absent, refused or stale: build again)."""
    from jax import export

    payload = read_entry(dir_fd, name, key)
    if payload is None:
        return None
    try:
        return exported_program(export.deserialize(bytearray(payload[0])), payload[1])
    except Exception:
        return None


def exported_program(exported, tree):
    """A function of the leaves that runs `exported`, and, as its `compile(*specs)`, compiles
    it without running: one jitted wrapper, so `prefetch` leaves in JAX's persistent cache
    exactly the executable a later call looks up."""
    import jax

    run = jax.jit(exported.call)

    def program(*leaves):
        return jax.tree.unflatten(tree, run(*leaves))

    program.compile = lambda *specs: run.lower(*specs).compile()
    return program


def serialize(compiled) -> bytes | None:
    """The pickled executable, or None when it cannot be stored (its output pytree does not
    survive pickling, e.g. an equinox module's): a property of the program, not of the disk."""
    from jax.experimental import serialize_executable

    try:
        payload = serialize_executable.serialize(compiled)
        blob = pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
        if not tree_survives(payload[2]):
            return None
    except Exception:                                       # a program that cannot be stored is no error
        return None
    return blob


def tree_survives(tree) -> bool:
    """Whether a pytree definition unflattens again after pickling (an equinox module's does
    not: its pickled definition holds a sentinel)."""
    try:
        pickle.loads(pickle.dumps(tree)).unflatten([0] * tree.num_leaves)
        return True
    except Exception:
        return False


def write(dir_fd: int, name: str, blob: bytes) -> bool:
    """Write `name` (mode 0600) in the checked folder `dir_fd` atomically (readers never see
    half a file; an entry of another user or a symbolic link of that name is replaced, not
    followed), then prune. Returns whether it was written; a failed write (disk full, read-only
    folder) leaves no temporary file and no marker: a later process tries again."""
    tmp = f".{name[:16]}.{secrets.token_hex(8)}.tmp"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0),
                     0o600, dir_fd=dir_fd)
    except OSError:                                         # a cache that cannot be written is no error
        return False
    try:
        with os.fdopen(fd, "wb") as file:
            file.write(blob)
        os.replace(tmp, name, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
    except Exception:
        with contextlib.suppress(OSError):
            os.unlink(tmp, dir_fd=dir_fd)
        return False
    with contextlib.suppress(Exception):
        _prune(dir_fd)
    return True


def _prune(dir_fd: int) -> None:
    """Remove the least recently used artifacts beyond `MAX_FILES` or `MAX_BYTES` (programs
    of older gfjax sources are never used again and go first), and temporaries that killed
    processes left behind."""
    stats = []
    now = time.time()
    with os.scandir(dir_fd) as entries:
        for entry in entries:
            try:
                info = entry.stat(follow_symlinks=False)
            except OSError:                                 # removed by another process
                continue
            if entry.name.endswith(SUFFIX):
                stats.append((info.st_mtime, info.st_size, entry.name))
            elif entry.name.startswith(".") and entry.name.endswith(".tmp") and now - info.st_mtime > _STALE_TMP_S:
                with contextlib.suppress(OSError):
                    os.unlink(entry.name, dir_fd=dir_fd)
    stats.sort(key=lambda item: item[0], reverse=True)      # newest first
    total = 0
    for count, (_, size, name) in enumerate(stats, start=1):
        total += size
        if count > MAX_FILES or total > MAX_BYTES:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(name, dir_fd=dir_fd)


def marker_present(dir_fd: int, name: str) -> bool:
    """Whether the plain-jit marker `name` is there, ours and writable by no one else."""
    try:
        info = os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
    except OSError:
        return False
    return (stat_.S_ISREG(info.st_mode) and info.st_uid == os.getuid()
            and not stat_.S_IMODE(info.st_mode) & 0o022)


def write_marker(dir_fd: int, name: str) -> None:
    """Mark the program `name` as one that cannot be stored (a property of the program)."""
    write(dir_fd, name, b"")
