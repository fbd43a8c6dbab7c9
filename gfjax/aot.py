"""Jitted programs kept across processes: compiled executables (or exported StableHLO) on disk.

A new `gfjax filter` process pays, per jitted program, tracing (Python), lowering (MLIR),
hashing the module for JAX's persistent compilation cache and loading the executable from
it. For DMF on an 824 k point tile that was 0.5 s of a 1.7 s process. `call(fn, *args,
**static)` pays it once: the program `fn(*args, **static)` is compiled (outside JAX's
compilation cache, see `_compile_fresh`), its executable serialized into `folder`
(`jax.experimental.serialize_executable`), and later processes load it and call it: no
tracing, no lowering, no hashing. A program with XLA custom calls (LAPACK on CPU) is exported
instead (`jax.export`, StableHLO): a later process skips tracing and lowers a thin wrapper,
and compiles through JAX's persistent cache.

Off by default (`call` is then `fn(*args, **static)`); `gfjax.cli` turns it on next to the
compilation cache, and `enable(folder)` does so in a notebook or a batch script. This module
imports JAX only when a program is called (`gfjax info` stays fast).

The key of a program: `fn`'s module and name, the static keyword arguments (their `repr`),
each argument's shape, dtype and weak type, the JAX and jaxlib versions, the backend and device kind,
the host CPU (machine and instruction-set flags: an executable is machine code), `XLA_FLAGS`,
the JAX options that change tracing, and a hash of the gfjax source files, so a change of
gfjax code, JAX, jaxlib or machine never runs a stale program. Only module-level gfjax
functions are cached by name; a closure or `functools.partial` needs a `tag` naming all it
binds (gfjax's callers give one), and anything else takes plain jit. Arguments must be
concrete (numpy or JAX arrays, numpy scalars): under `jit`, `vmap` or `grad`, `call` is
`fn(*args, **static)`. A missing, unreadable or stale artifact is compiled again; a program
that cannot be stored (custom calls that cannot be exported, an output pytree that does not
survive pickling) leaves a marker and runs through plain jit in later processes.

A program whose `jax.jit` donates arguments (`donate_argnums`) donates them stored too: the
stored executable may write its result into those arguments' buffers (a loop state handed
from call to call then never exists twice); the key records which. An exported program
(custom calls) does not donate.

The files hold pickled pytree definitions next to machine code, so nothing another user could
have written is ever loaded. The folder must be private: owned by this user, mode 0700 (`enable`
creates it so, and tightens a folder of ours that others can only read), and every folder above
it owned by root or this user and writable by no one else (unless sticky, as `/tmp`). That is
checked again each time a program is looked up, not only at `enable`: the path is walked from
`/` one folder at a time with `O_NOFOLLOW` (a folder swapped for a symbolic link is refused),
and each file is opened relative to the checked folder's descriptor, with `O_NOFOLLOW`, then
checked on that descriptor (a regular file owned by this user, writable by no one else) before
a byte of it is unpickled. An entry carries its key and the SHA-256 of its contents: a file
swapped for another entry, truncated or stale is compiled again and replaced. A refused folder
or file means plain compilation, with one warning line on stderr per process; a write that
fails (disk full) stores nothing this time and leaves no marker.
"""
from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import importlib.util
import os
import pickle
import platform
import secrets
import stat as stat_
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

__all__ = ["enable", "disable", "release", "enabled_folder", "private_folder", "call", "programs", "prefetch", "prefetching", "program_key",
           "on_compile",
           "MAX_FILES", "MAX_BYTES"]

MAX_FILES = 512                 # artifacts kept (least recently used go first); each is ~0.1-2 MB
MAX_BYTES = 256 * 2**20         # ... and their total size
_SUFFIX = ".gfjaxexe"
_EXPORT_SUFFIX = ".export" + _SUFFIX  # a program with custom calls: exported StableHLO
_PLAIN_SUFFIX = ".plain" + _SUFFIX    # marker: this program is not stored, run it through plain jit
_MAGIC = b"gfjax-aot 1\n"           # an entry: magic, key, SHA-256 of the body, pickled body
_MAX_ENTRY_BYTES = 64 * 2**20         # a larger file is refused unread
_STALE_TMP_S = 3600.0                 # temporaries older than this are left by killed processes

_state: dict[str, Any] = {"folder": None, "fingerprint": None, "warned": False}
_loaded: dict[str, Any] = {}    # key -> program of the argument leaves, for this process
_from_disk: set[str] = set()    # keys of `_loaded` programs read from a file
_plain: set[str] = set()        # keys of programs that run through plain jit (custom calls)
_lock = threading.Lock()        # one compile at a time (`_compile_fresh`)
_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
_FILE_FLAGS = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NONBLOCK", 0)


class _Refused(Exception):
    """A folder or file another user could have written (the message says why)."""


def enable(folder: str | os.PathLike) -> Path | None:
    """Keep compiled programs in `folder` (see `private_folder`). Returns the folder (symbolic
    links resolved), or None, with one warning line on stderr, when it is refused: the cache
    then stays off and every program compiles as plain jit."""
    checked = private_folder(folder)
    _state["folder"] = checked
    return checked


def disable() -> None:
    """Turn the cache off (`call` is then `fn(*args, **static)`)."""
    _state["folder"] = None
    _loaded.clear()
    _from_disk.clear()
    _plain.clear()


def release() -> None:
    """Drop the programs this process holds (ours and `jax.jit`'s), so their memory goes back.

    Each compiled XLA CPU program keeps its code mapped, in several memory maps, and a process
    may hold 65,530 maps (`vm.max_map_count`): a job that compiles many shapes one after the
    other (a grid search over a method's static settings: DMF's grid takes 6,000-8,500 maps
    per ISPRS sample) releases them between its parts. The folder stays on; a program needed
    again is read back from it (or from JAX's persistent cache) instead of compiled again.
    """
    import jax

    _loaded.clear()
    _from_disk.clear()
    jax.clear_caches()


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
            raise _Refused("this system cannot open files relative to a folder (no O_NOFOLLOW, dir_fd)")
        os.makedirs(path, mode=0o700, exist_ok=True)
        path = Path(os.path.realpath(path))
        fd = _open_folder(path, tighten=True)
        os.close(fd)
    except (_Refused, OSError) as err:
        _warn_once(f"{_reason(err, folder)}; running without the {what}")
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
    """`_warn_once` for the other caches of the process (`gfjax.cache`): one line in all."""
    _warn_once(message)


def _supported() -> bool:
    return (hasattr(os, "O_NOFOLLOW") and hasattr(os, "getuid") and os.open in os.supports_dir_fd
            and os.unlink in os.supports_dir_fd and os.rename in os.supports_dir_fd
            and os.scandir in os.supports_fd)


def _reason(err: Exception, folder) -> str:
    """One line: what is wrong with `folder` or a folder above it."""
    if isinstance(err, OSError) and err.errno in (errno.ELOOP, errno.ENOTDIR):
        return f"{err.filename or folder}: a symbolic link or not a folder"
    if isinstance(err, OSError):
        return f"{err.filename or folder}: {err.strerror or err}"
    return str(err)


def _warn_once(message: str) -> None:
    """One line on stderr, the first time a cache is refused in this process."""
    if not _state["warned"]:
        _state["warned"] = True
        print(f"gfjax: warning: {message}", file=sys.stderr)


def _open_folder(path: Path, *, tighten: bool = False) -> int:
    """A descriptor of the folder `path` (absolute, symbolic links resolved), opened one folder
    at a time from `/` with `O_NOFOLLOW`, each checked on its own descriptor (see
    `private_folder`). With `tighten`, the folder itself is set to 0700 when it is ours and
    others may only read it. Raises `_Refused` or `OSError` (a symbolic link: `ELOOP`)."""
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
        raise _Refused(f"{where} is not a folder")
    if last:
        if info.st_uid != uid:
            raise _Refused(f"{where} is owned by user {info.st_uid}, not by this user ({uid})")
        if mode & 0o022:
            raise _Refused(f"{where} can be written by other users (mode {mode:04o}; it must be 0700)")
        if mode & 0o077 and tighten:                          # ours, others may only read: tighten
            os.fchmod(fd, 0o700)
        elif mode & 0o077:
            raise _Refused(f"{where} is not private (mode {mode:04o}; it must be 0700)")
    else:
        if info.st_uid not in (0, uid):
            raise _Refused(f"{where} is owned by user {info.st_uid}, neither root nor this user ({uid})")
        if mode & 0o022 and not mode & stat_.S_ISVTX:
            raise _Refused(f"{where} can be written by other users (mode {mode:04o})")


def _check_file(fd: int, name: str) -> os.stat_result:
    """The status of an opened cache file, if only this user could have written it."""
    info = os.fstat(fd)
    mode = stat_.S_IMODE(info.st_mode)
    if not stat_.S_ISREG(info.st_mode):
        raise _Refused(f"{name} is not a regular file")
    if info.st_uid != os.getuid():
        raise _Refused(f"{name} is owned by user {info.st_uid}, not by this user ({os.getuid()})")
    if mode & 0o022:
        raise _Refused(f"{name} can be written by other users (mode {mode:04o})")
    if info.st_size > _MAX_ENTRY_BYTES:
        raise _Refused(f"{name} is larger than {_MAX_ENTRY_BYTES} bytes")
    return info


def enabled_folder() -> Path | None:
    """The cache folder, or None when the cache is off."""
    return _state["folder"]


def _cpu_flags() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as file:
            for line in file:
                if line.startswith(("flags", "Features")):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def _fingerprint() -> str:
    """sha256 of what makes an executable valid here, once per process: every
    `gfjax/**/*.py` (path and bytes), the JAX/jaxlib versions, backend, device kind, CPU."""
    if _state["fingerprint"] is None:
        import jax
        import jaxlib

        root = Path(__file__).resolve().parent
        digest = hashlib.sha256()
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
        device = jax.devices()[0]
        try:
            from jax.extend import backend as jax_backend

            platform_version = jax_backend.get_backend().platform_version
        except Exception:  # pragma: no cover (another JAX)
            platform_version = ""
        for part in (jax.__version__, jaxlib.__version__, device.platform, device.device_kind,
                     platform_version, platform.machine(), _cpu_flags(),
                     os.environ.get("XLA_FLAGS", ""), importlib.util.find_spec("flatbuffers") is not None):
            digest.update(str(part).encode() + b"\0")
        _state["fingerprint"] = digest.hexdigest()
    return _state["fingerprint"]


def _concrete(x) -> bool:
    import jax
    import numpy as np

    return isinstance(x, (np.ndarray, np.generic)) or (isinstance(x, jax.Array) and not isinstance(x, jax.core.Tracer))


def _dtype(x):
    import numpy as np

    return np.dtype(x.dtype) if hasattr(x, "dtype") else np.result_type(x)


def _name(fn) -> str | None:
    return getattr(fn, "__qualname__", None) or getattr(fn, "__name__", None)


def _donated(fn) -> tuple[int, ...]:
    """The positional arguments `fn`'s `jax.jit` donates (`donate_argnums`), or `()`."""
    info = getattr(fn, "_jit_info", None)
    return tuple(sorted(getattr(info, "donate_argnums", None) or ()))


def _donated_leaves(fn, args: tuple) -> tuple[int, ...]:
    """The indices, among the leaves of `args`, of the leaves of the arguments `fn` donates."""
    import jax

    donated, out, start = set(_donated(fn)), [], 0
    for i, arg in enumerate(args):
        count = len(jax.tree.leaves(arg))
        if i in donated:
            out.extend(range(start, start + count))
        start += count
    return tuple(out)


def _cacheable(fn, tag) -> bool:
    """A program the key can tell apart: tagged, or a module-level gfjax function (its code is
    in the fingerprint). Closures, partials and functions from elsewhere take plain jit."""
    if tag is not None:
        return True
    name, module = _name(fn), getattr(fn, "__module__", None) or ""
    return bool(name) and "<locals>" not in name and (module == "gfjax" or module.startswith("gfjax."))


def _trace_options() -> str:
    """The JAX options that enter jit's own cache key (default device, PRNG, x64, promotion,
    ...), or, should that private tuple move or show object addresses, the main ones."""
    import jax

    try:
        from jax._src import config as jax_config

        text = repr(jax_config.trace_context())
        if " at 0x" not in text:
            return text
    except Exception:  # pragma: no cover (another JAX)
        pass
    names = ("jax_enable_x64", "jax_default_matmul_precision", "jax_numpy_dtype_promotion", "jax_default_device",
             "jax_threefry_partitionable", "jax_default_prng_impl")
    return repr([(name, getattr(jax.config, name, None)) for name in names])


_REPRS: dict[int, tuple[Any, str]] = {}   # id -> (value kept alive, its repr)
_MAX_REPRS = 64


def _static_repr(static: dict) -> str:
    """`repr` of the sorted static arguments; the repr of each value is remembered by identity
    (a network's skeleton takes 80 ms to print, and a caller passes the same one per call)."""
    parts = []
    for name, value in sorted(static.items()):
        known = _REPRS.get(id(value))
        if known is None or known[0] is not value:
            if len(_REPRS) >= _MAX_REPRS:
                _REPRS.clear()
            known = _REPRS[id(value)] = (value, repr(value))
        parts.append(f"({name!r}, {known[1]})")
    return "[" + ", ".join(parts) + "]"


def _placement(a) -> str:
    """The sharding of an argument committed elsewhere than the default device; "" for one on
    it, committed or not (the same program runs both: an output of an exported program is
    committed, the spec `prefetch` gets for it is not)."""
    import jax

    if not (isinstance(a, jax.Array) and a.committed):
        return ""
    devices = a.sharding.device_set
    return "" if len(devices) == 1 and next(iter(devices)) == jax.devices()[0] else repr(a.sharding)


def program_key(fn: Callable, args: tuple, static: dict, tag=None) -> str:
    """The cache key of `fn(*args, **static)` (hex sha256; see the module docstring). `tag`,
    when given, names the program instead of `fn`'s module and name."""
    import jax
    import numpy as np

    leaves, treedef = jax.tree.flatten(args)
    signature = [f"{np.shape(a)}:{_dtype(a)}:{'weak' if getattr(a, 'weak_type', False) else ''}:{_placement(a)}"
                 for a in leaves]
    name = repr(tag) if tag is not None else f"{fn.__module__}.{_name(fn)}"
    parts = [name, _static_repr(static), str(treedef), ";".join(signature), _trace_options(), _fingerprint()]
    donated = _donated(fn)
    if donated:
        parts.append(f"donate {donated}")
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _read_entry(dir_fd: int, name: str, key: str):
    """The unpickled body of the entry `name` in the checked folder `dir_fd`, or None when it
    is absent, unreadable, or holds another key or a damaged body (compile again and replace
    it). A file another user could have written is refused before a byte of it is read (one
    warning line). A hit refreshes the file's time (least recently used files go first)."""
    try:
        fd = os.open(name, _FILE_FLAGS, dir_fd=dir_fd)
    except FileNotFoundError:
        return None
    except OSError as err:
        if err.errno == errno.ELOOP:
            _warn_once(f"program cache entry {name}: a symbolic link; compiling it again")
        return None
    try:
        try:
            info = _check_file(fd, name)
        except _Refused as err:
            _warn_once(f"program cache entry {err}; compiling it again")
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


def _wrap(key: str, body: bytes) -> bytes:
    return _MAGIC + key.encode() + b"\n" + hashlib.sha256(body).hexdigest().encode() + b"\n" + body


def _unwrap(blob: bytes, key: str) -> bytes | None:
    """The body of an entry, if it is one for `key` and intact."""
    header = _MAGIC + key.encode() + b"\n"
    if not blob.startswith(header):
        return None
    digest, sep, body = blob[len(header):].partition(b"\n")
    if not sep or digest != hashlib.sha256(body).hexdigest().encode():
        return None
    return body


def _load(dir_fd: int, name: str, key: str):
    """The stored executable `name`, or None (absent, refused or stale: compile again)."""
    from jax.experimental import serialize_executable

    payload = _read_entry(dir_fd, name, key)
    if payload is None:
        return None
    try:
        return serialize_executable.deserialize_and_load(*payload)
    except Exception:
        return None


def _serialize(compiled) -> bytes | None:
    """The pickled executable, or None when it cannot be stored (its output pytree does not
    survive pickling, e.g. an equinox module's): a property of the program, not of the disk."""
    from jax.experimental import serialize_executable

    try:
        payload = serialize_executable.serialize(compiled)
        blob = pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
        if not _tree_survives(payload[2]):
            return None
    except Exception:                                       # a program that cannot be stored is no error
        return None
    return blob


def _tree_survives(tree) -> bool:
    """Whether a pytree definition unflattens again after pickling (an equinox module's does
    not: its pickled definition holds a sentinel)."""
    try:
        pickle.loads(pickle.dumps(tree)).unflatten([0] * tree.num_leaves)
        return True
    except Exception:
        return False


def _write(dir_fd: int, name: str, blob: bytes) -> bool:
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
            if entry.name.endswith(_SUFFIX):
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


def call(fn: Callable, *args, tag=None, **static):
    """`fn(*args, **static)`, through the on-disk program cache when it is on.

    Args:
      fn: a `jax.jit`-wrapped function whose keyword arguments `static` are all static
        (hashable; their `repr` enters the key).
      args: pytrees of concrete arrays (numpy or JAX) or numpy scalars.
      tag: names the program in the key instead of `fn`'s module and name; needed when `fn`
        is a closure or a `functools.partial` (give everything it binds, e.g. its config,
        with a stable `repr`).

    Returns: what `fn` returns.
    """
    import jax

    folder = _state["folder"]
    if _state.get("prefetching"):
        prefetch(fn, *args, tag=tag, **static)
        return jax.eval_shape(lambda *a: fn(*a, **static), *args)
    leaves = jax.tree.leaves(args)
    if folder is None or jax.config.jax_disable_jit or not _cacheable(fn, tag) or not all(map(_concrete, leaves)):
        return fn(*args, **static)
    key = program_key(fn, args, static, tag)
    compiled = _loaded.get(key)
    if compiled is None and key not in _plain:
        compiled = _load_or_compile(fn, args, static, folder, key, _module(fn, tag))
    if compiled is None:                                    # not storable, or refused: plain jit
        return fn(*args, **static)
    if key not in _from_disk:
        return compiled(*leaves)
    try:
        return compiled(*leaves)
    except Exception:             # a stored program that does not fit its caller: plain jit,
        _forget(folder, key)      # and the next call compiles and stores it again
        return fn(*args, **static)


def programs(package: str, stages: Sequence[tuple[str, Callable, Any]], *, key: tuple,
             batched: bool) -> tuple[Callable, ...]:
    """A method's stages as programs: each `(name, fn, in_axes)` of `stages` becomes
    `jax.jit(fn)` (of `jax.vmap(fn, in_axes)` when `batched`: a batch of tiles) called through
    `call`, tagged `(f"{package}.{name}", *key, batched)`. `key` holds what `fn` binds (its
    static config, the raster shape), so the tag names one program. Each stage compiles apart:
    a costly raster stage compiles once per raster shape, a cheap point stage again for each
    point capacity."""
    import jax

    out = []
    for name, fn, in_axes in stages:
        program = jax.jit(jax.vmap(fn, in_axes=in_axes) if batched else fn)
        out.append(functools.partial(call, program, tag=(f"{package}.{name}", *key, batched)))
    return tuple(out)


def _forget(folder: Path, key: str) -> None:
    """Drop the program of `key` from this process and its entries from the folder."""
    _loaded.pop(key, None)
    _from_disk.discard(key)
    try:
        dir_fd = _open_folder(folder)
    except (_Refused, OSError):
        return
    try:
        for suffix in (_SUFFIX, _EXPORT_SUFFIX):
            with contextlib.suppress(OSError):
                os.unlink(f"{key}{suffix}", dir_fd=dir_fd)
    finally:
        os.close(dir_fd)


def prefetch(fn: Callable, *specs, tag=None, **static) -> None:
    """Load (or compile and store) the program `call(fn, *args, **static)` will run for
    arguments of these shapes and dtypes, without running it: from a worker thread, a
    program's load overlaps other work (loading holds no GIL). Nothing when the cache is off.

    Args:
      specs: `jax.ShapeDtypeStruct` (or arrays) standing for the positional arguments.
    """
    folder = _state["folder"]
    if folder is None or not _cacheable(fn, tag):
        return
    key = program_key(fn, specs, static, tag)
    program = _loaded.get(key)
    if program is None and key not in _plain:
        program = _load_or_compile(fn, specs, static, folder, key, _module(fn, tag))
    if hasattr(program, "compile"):       # exported: its executable lives in JAX's cache
        import jax

        program.compile(*jax.tree.leaves(specs))


@contextlib.contextmanager
def prefetching():
    """Within this context `call` runs nothing: it loads (or compiles and stores) the program
    and returns the shapes and dtypes of its result (`jax.ShapeDtypeStruct`s), so a driver
    called with `jax.ShapeDtypeStruct` inputs prepares every program a real call of those
    shapes would run (`gfjax warmup`). Nothing is stored when the cache is off."""
    before = _state.get("prefetching", False)
    _state["prefetching"] = True
    try:
        yield
    finally:
        _state["prefetching"] = before


def warm_all(jobs: Sequence[Callable[[], Any]], *, progress: bool = False, desc: str = "programs") -> int:
    """Run `jobs` (each prepares one program: `prefetch`, or a driver under `prefetching`) in
    turn, with a progress bar over them when `progress`. One at a time: XLA already compiles a
    program on every core (two at once took as long on 2 cores). Returns `len(jobs)` (a
    method's `warm`, `gfjax warmup`)."""
    if progress:
        from tqdm.auto import tqdm
        jobs = tqdm(jobs, desc=desc, unit="program")
    with prefetching():
        for job in jobs:
            job()
    return len(jobs)


def on_compile(callback: Callable[[str], None] | None) -> None:
    """Call `callback(module)` just before a program is compiled rather than loaded (`module`:
    the compiled function's module, e.g. `gfjax.smrf.stages`), so a command can say that it is
    compiling instead of sitting silent; None: no calls."""
    _state["on_compile"] = callback


def _module(fn, tag) -> str:
    """The module a program belongs to, for `on_compile`: a tag's leading dotted name (e.g.
    "gfjax.smrf.rasterize_min" -> "gfjax.smrf"; a tagged program is often a partial, whose own
    module is functools'), else `fn`'s module."""
    head = tag[0] if isinstance(tag, tuple) and tag else tag
    if isinstance(head, str) and head.startswith("gfjax."):
        return head.rsplit(".", 1)[0]
    return getattr(fn, "__module__", None) or "gfjax"


def _load_or_compile(fn, args, static, folder: Path, key: str, module: str):
    """The stored program of `key` (a function of the leaves of `args`), loaded or built and
    stored; None when it runs through plain jit: it cannot be stored (a marker file then says
    so to later processes), or the folder is refused now (one warning line)."""
    try:
        dir_fd = _open_folder(folder)
    except (_Refused, OSError) as err:
        _warn_once(f"{_reason(err, folder)}; compiling without the program cache")
        return None
    try:
        return _load_or_compile_in(fn, args, static, dir_fd, key, module)
    finally:
        os.close(dir_fd)


def _load_or_compile_in(fn, args, static, dir_fd: int, key: str, module: str):
    name, exported, marker = (f"{key}{suffix}" for suffix in (_SUFFIX, _EXPORT_SUFFIX, _PLAIN_SUFFIX))
    if _marker_present(dir_fd, marker):
        _plain.add(key)
        return None
    program = _load(dir_fd, name, key)                     # loads run in parallel (no GIL held)
    if program is None:
        program = _load_exported(dir_fd, exported, key)
    if program is not None:
        _from_disk.add(key)
    else:
        if _state.get("on_compile") is not None:
            _state["on_compile"](module)
        compiled, fresh = _compile_fresh(fn, args, static)
        if compiled is not None:
            program = compiled
            if fresh:                                       # else JAX's cache gave it: not stored
                blob = _serialize(compiled)
                if blob is None:                            # later processes: plain jit,
                    _write_marker(dir_fd, marker)           # through JAX's cache
                else:
                    _write(dir_fd, name, _wrap(key, blob))   # disk full: stored next time
        else:                                               # custom calls: exported StableHLO
            program, blob = _export(fn, args, static)
            if program is None:
                _plain.add(key)
                _write_marker(dir_fd, marker)
                return None
            _write(dir_fd, exported, _wrap(key, blob))
    _loaded[key] = program
    return program


def _export(fn, args, static):
    """`(program, blob)`: the program exported with `jax.export` (StableHLO; custom calls are
    kept by name, so it stays valid in another process, which lowers a thin wrapper around it
    and compiles through JAX's persistent cache), as a function of the leaves of `args`, and
    its serialized form; `(None, None)` when it cannot be exported or serialized (no
    `flatbuffers`, or a custom call jax.export does not guarantee)."""
    import jax
    import numpy as np
    from jax import export

    if importlib.util.find_spec("flatbuffers") is None:    # jax.export's serialization format
        return None, None
    out = {}
    program, leaves = _leaf_program(fn, args, static, out=out)
    try:
        specs = [jax.ShapeDtypeStruct(np.shape(a), _dtype(a)) for a in leaves]
        exported = export.export(jax.jit(program))(*specs)
        blob = pickle.dumps((bytes(exported.serialize()), out["tree"]), protocol=pickle.HIGHEST_PROTOCOL)
        if not _tree_survives(out["tree"]):
            return None, None
    except Exception:
        return None, None
    return _exported_program(exported, out["tree"]), blob


def _exported_program(exported, tree):
    """A function of the leaves that runs `exported`, and, as its `compile(*specs)`, compiles
    it without running: one jitted wrapper, so `prefetch` leaves in JAX's persistent cache
    exactly the executable a later call looks up."""
    import jax

    run = jax.jit(exported.call)

    def program(*leaves):
        return jax.tree.unflatten(tree, run(*leaves))

    program.compile = lambda *specs: run.lower(*specs).compile()
    return program


def _load_exported(dir_fd: int, name: str, key: str):
    """The exported program `name`, or None (absent, refused or stale: build again)."""
    from jax import export

    payload = _read_entry(dir_fd, name, key)
    if payload is None:
        return None
    try:
        return _exported_program(export.deserialize(bytearray(payload[0])), payload[1])
    except Exception:
        return None


def _marker_present(dir_fd: int, name: str) -> bool:
    """Whether the plain-jit marker `name` is there, ours and writable by no one else."""
    try:
        info = os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
    except OSError:
        return False
    return (stat_.S_ISREG(info.st_mode) and info.st_uid == os.getuid()
            and not stat_.S_IMODE(info.st_mode) & 0o022)


def _write_marker(dir_fd: int, name: str) -> None:
    """Mark the program `name` as one that cannot be stored (a property of the program)."""
    _write(dir_fd, name, b"")


def _leaf_program(fn, args, static, *, out: dict | None = None):
    """`(program, leaves)`: `fn(*args, **static)` as a function of the leaves of `args`, named
    `gfjax_aot_<name>`. With `out`, the program returns the leaves of its result and puts their
    pytree definition in `out["tree"]` when traced."""
    import jax

    leaves, treedef = jax.tree.flatten(args)

    def program(*arrays):
        result = fn(*jax.tree.unflatten(treedef, arrays), **static)
        if out is None:
            return result
        flat, out["tree"] = jax.tree.flatten(result)
        return flat

    program.__name__ = program.__qualname__ = f"gfjax_aot_{(_name(fn) or 'program').replace('.', '_')}"
    return program, leaves


def _compile_fresh(fn, args, static):
    """Compile `fn(*args, **static)` outside JAX's persistent compilation cache.

    An executable that JAX loaded from its cache serializes incompletely (jaxlib 0.10.2, CPU:
    a later process fails with "Function ... not found"), so the program is lowered under a
    name of its own (`gfjax_aot_<name>`: its own cache key, never an entry written by plain
    `jit`) and compiled with cache writes off for this thread, so its key never enters that
    cache either.
    The stored program takes the leaves of `args` (a pickled pytree definition of, say, an
    equinox module does not unflatten again). A program with XLA custom calls (LAPACK on CPU:
    bound to the compiling process) is not compiled here: its executable crashes when run in
    another process (SMRF's harmonic fill, jaxlib 0.10.2 CPU: a segmentation fault).

    The arguments `fn`'s `jax.jit` donates are donated by the stored program too.

    Returns: `(compiled, fresh)`: `(None, False)` for a program with custom calls; `fresh` is
    False if JAX reports a cache hit all the same (then it is used but not stored).
    """
    import jax

    program, leaves = _leaf_program(fn, args, static)
    lowered = jax.jit(program, donate_argnums=_donated_leaves(fn, args)).lower(*leaves)
    if "custom_call" in lowered.as_text():
        return None, False
    _watch_cache_hits()
    _hits.count = 0
    try:                              # this thread only: other threads keep writing the cache
        from jax._src import config as jax_config

        no_writes = jax_config.persistent_cache_min_compile_time_secs(float("inf"))
    except Exception:  # pragma: no cover (another JAX: the global option, one compile at a time)
        no_writes = None
    if no_writes is not None:
        with no_writes:
            compiled = lowered.compile()
    else:  # pragma: no cover
        with _lock:
            before = jax.config.jax_persistent_cache_min_compile_time_secs
            jax.config.update("jax_persistent_cache_min_compile_time_secs", float("inf"))
            try:
                compiled = lowered.compile()
            finally:
                jax.config.update("jax_persistent_cache_min_compile_time_secs", before)
    return compiled, _hits.count == 0


_hits = threading.local()             # JAX cache hits seen by this thread's compile


def _watch_cache_hits() -> None:
    if _state.get("watching"):
        return
    import jax

    def listen(event: str, **_):
        if event == "/jax/compilation_cache/cache_hits":
            _hits.count = getattr(_hits, "count", 0) + 1

    jax.monitoring.register_event_listener(listen)
    _state["watching"] = True
