"""Jitted programs kept across processes: compiled executables (or exported StableHLO) on disk.

A new `gfjax filter` process pays, per jitted program, tracing (Python), lowering (MLIR),
hashing the module for JAX's persistent compilation cache and loading the executable from
it. For DMF on an 824 k point tile that was 0.5 s of a 1.7 s process. `call(fn, *args,
**static)` pays it once: the program `fn(*args, **static)` is compiled (outside JAX's
compilation cache, see `build.compile_fresh`), its executable serialized into the folder
(`jax.experimental.serialize_executable`), and later processes load it and call it: no
tracing, no lowering, no hashing. A program with XLA custom calls (LAPACK on CPU) is exported
instead (`jax.export`, StableHLO): a later process skips tracing and lowers a thin wrapper,
and compiles through JAX's persistent cache.

Off by default (`call` is then `fn(*args, **static)`); `gfjax.cli` turns it on next to the
compilation cache, and `enable(folder)` does so in a notebook or a batch script. The package
imports JAX only when a program is called (`gfjax info` stays fast). Arguments must be concrete
(numpy or JAX arrays, numpy scalars): under `jit`, `vmap` or `grad`, `call` is
`fn(*args, **static)`. A missing, unreadable or stale artifact is compiled again; a program
that cannot be stored (custom calls that cannot be exported, an output pytree that does not
survive pickling) leaves a marker and runs through plain jit in later processes.

A program whose `jax.jit` donates arguments (`donate_argnums`) donates them stored too: the
stored executable may write its result into those arguments' buffers (a loop state handed
from call to call then never exists twice); the key records which. An exported program
(custom calls) does not donate.

Modules, each one concern:
- `folder`: the folder and each file checked before a byte is read (private to this user, no
  symbolic link followed); the one warning line of a refused cache.
- `keys`: what names a program (function or tag, static arguments, shapes, the machine, the
  gfjax sources), and which programs a key can tell apart.
- `store`: the entries on disk: read and checked, unpickled, written atomically, pruned.
- `build`: a program compiled outside JAX's persistent cache, or exported.
- `calls`: the on/off switch, `call`, and the programs prepared ahead (`prefetch`, `warm_all`).
"""
from gfjax.aot.calls import (
    call,
    disable,
    enable,
    enabled_folder,
    on_compile,
    prefetch,
    prefetching,
    programs,
    release,
    warm_all,
)
from gfjax.aot.folder import planted_entry, private_folder, warn_once
from gfjax.aot.keys import program_key
from gfjax.aot.store import MAX_BYTES, MAX_FILES

__all__ = ["enable", "disable", "release", "enabled_folder", "private_folder", "planted_entry", "warn_once", "call",
           "programs", "prefetch", "prefetching", "warm_all", "program_key", "on_compile", "MAX_FILES", "MAX_BYTES"]
