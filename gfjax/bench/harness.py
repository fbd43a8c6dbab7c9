"""A timing harness for ground filters: warm-up, repeated wall times, JAX compile time, peak RSS.

The one clock of `gfjax bench` and of the experiments in `experiments/`: `Stopwatch` (wall and
process CPU seconds of a stretch of code) and `time_call` (warm-up calls, then repeated timed
calls, each on a `Stopwatch`). STYLE.md "Benchmarks": warm up once, then time the call until
its result is on the host (our filters return host numpy arrays, so `fn()` returning is the
end of the work; pass `block=True` to `time_call` for functions that return JAX arrays, or
wait for them inside the `Stopwatch`'s block). Compile time is reported
apart: `CompileClock` sums the durations JAX itself records for each XLA compilation
(`jax.monitoring` event `/jax/core/compile/backend_compile_duration`) and for tracing and
lowering, so no second compile is needed to measure it.

Peak memory of one run is read in a fresh interpreter (`run_isolated`): a child process runs
one target function and reports its own high-water mark (`VmHWM` of `/proc/self/status`,
else `ru_maxrss`), so earlier runs never inflate a later run's peak.

Used by `gfjax bench` (`gfjax.bench.run`) and by the speed experiments in `experiments/`.
"""
from __future__ import annotations

import dataclasses
import importlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

# JAX events (jax._src.dispatch) whose durations make up compilation, in seconds.
BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
CACHE_HIT_EVENT = "/jax/compilation_cache/cache_hits"   # a program loaded from the persistent cache
TRACE_LOWER_EVENTS = ("/jax/core/compile/jaxpr_trace_duration",
                      "/jax/core/compile/jaxpr_to_mlir_module_duration")
# Environment variables that switch JAX's persistent compilation cache on (gfjax.cache):
# removed in isolated runs so that compile times are those of a cold start.
_CACHE_ENV = ("JAX_COMPILATION_CACHE_DIR", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS",
              "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "JAX_COMPILATION_CACHE_MAX_SIZE")
_MIB = 1 << 20


class Stopwatch:
    """Wall-clock and process CPU seconds of a stretch of code (`time.perf_counter`,
    `time.process_time`: CPU time of every thread of this process).

        with Stopwatch() as watch:
            ground = method.filter(cloud).ground
        watch.wall_s, watch.cpu_s

    It starts when made (and again on entering a `with` block) and stops on leaving the block
    or at `stop()`; until it stops, `wall_s` and `cpu_s` read the time so far (a progress
    line, the total of a long run). JAX arrays made inside are timed to their end only when
    waited for inside (`jax.block_until_ready`).
    """

    def __init__(self) -> None:
        self.restart()

    def restart(self) -> Stopwatch:
        """Start again from now, running."""
        self._end: tuple[float, float] | None = None
        self._cpu_start = time.process_time()
        self._wall_start = time.perf_counter()          # read last: the CPU clock's read is not timed
        return self

    def stop(self) -> Stopwatch:
        """Stop the clock (once: a later call keeps the first stop)."""
        if self._end is None:
            wall = time.perf_counter()                  # read first, as the start's wall clock was last
            self._end = (wall, time.process_time())
        return self

    @property
    def running(self) -> bool:
        return self._end is None

    @property
    def wall_s(self) -> float:
        """Wall-clock seconds from the start to the stop (to now while running)."""
        return (time.perf_counter() if self._end is None else self._end[0]) - self._wall_start

    @property
    def cpu_s(self) -> float:
        """Process CPU seconds (all threads) from the start to the stop (to now while running)."""
        return (time.process_time() if self._end is None else self._end[1]) - self._cpu_start

    def __enter__(self) -> Stopwatch:
        return self.restart()

    def __exit__(self, *exc: Any) -> None:
        self.stop()


@dataclasses.dataclass(frozen=True)
class Timing:
    """Wall times of one function: warm-up calls, then `repeat` timed calls [s]."""

    warmup_s: tuple[float, ...]   # the untimed-for-the-median calls (first one includes compiles)
    times_s: tuple[float, ...]    # the timed calls, in order
    cpu_times_s: tuple[float, ...] = ()   # process CPU seconds of the timed calls, in order

    @property
    def median_s(self) -> float:
        return statistics.median(self.times_s)

    @property
    def min_s(self) -> float:
        return min(self.times_s)

    @property
    def median_cpu_s(self) -> float:
        return statistics.median(self.cpu_times_s)


def _block(value: Any) -> Any:
    """Wait for every JAX array in `value` (a pytree) to be computed."""
    jax = sys.modules.get("jax")
    if jax is None:
        return value
    return jax.block_until_ready(value)


def time_call(fn: Callable[[], Any], *, repeat: int = 3, warmup: int = 1,
              block: bool = False) -> tuple[Timing, Any]:
    """Call `fn()` `warmup` times, then `repeat` timed times; return the timing and last result.

    Each call is timed on its own `Stopwatch` (wall and process CPU seconds).

    Args:
      fn: a function of no arguments (close over the inputs).
      repeat: timed calls (>= 1).
      warmup: calls before the timed ones (>= 0); their times are kept in `Timing.warmup_s`.
      block: wait for JAX arrays in the result (`jax.block_until_ready`) inside each timing.

    Returns:
      `(Timing, result of the last call)`.
    """
    if repeat < 1 or warmup < 0:
        raise ValueError(f"repeat must be >= 1 and warmup >= 0, got repeat={repeat}, warmup={warmup}")
    result = None
    warm, timed, cpu = [], [], []
    for i in range(warmup + repeat):
        with Stopwatch() as watch:
            result = fn()
            if block:
                result = _block(result)
        if i < warmup:
            warm.append(watch.wall_s)
        else:
            timed.append(watch.wall_s)
            cpu.append(watch.cpu_s)
    return Timing(tuple(warm), tuple(timed), tuple(cpu)), result


class CompileClock:
    """Seconds JAX spends compiling while the clock is open (a `jax.monitoring` listener).

    `compile_s` sums XLA backend compilations; `trace_lower_s` sums tracing to jaxprs and
    lowering to MLIR (a nested `jit` traced inside another may count twice there). Hits of
    the persistent compilation cache record no backend compile; `n_cache_hits` counts them.
    Use as a context manager:

        with CompileClock() as clock:
            method.filter(cloud)
        clock.compile_s, clock.n_compiles
    """

    def __init__(self) -> None:
        self.compile_s = 0.0
        self.trace_lower_s = 0.0
        self.n_compiles = 0
        self.n_cache_hits = 0
        self._monitoring = None

    def _count(self, event: str, **_: Any) -> None:
        if event == CACHE_HIT_EVENT:
            self.n_cache_hits += 1

    def _listen(self, event: str, duration_s: float, **_: Any) -> None:
        if event == BACKEND_COMPILE_EVENT:
            self.compile_s += float(duration_s)
            self.n_compiles += 1
        elif event in TRACE_LOWER_EVENTS:
            self.trace_lower_s += float(duration_s)

    def __enter__(self) -> CompileClock:
        import jax.monitoring

        self._monitoring = jax.monitoring
        jax.monitoring.register_event_duration_secs_listener(self._listen)
        jax.monitoring.register_event_listener(self._count)
        return self

    def __exit__(self, *exc: Any) -> None:
        self._monitoring.unregister_event_duration_listener(self._listen)
        self._monitoring.unregister_event_listener(self._count)


def _status_kib(field: str) -> int | None:
    """A `kB` field of `/proc/self/status` (Linux), or None."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def peak_rss_bytes() -> int:
    """Peak resident set size of this process so far [bytes] (VmHWM, else ru_maxrss)."""
    kib = _status_kib("VmHWM")
    if kib is not None:
        return kib * 1024
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024   # bytes on macOS, KiB on Linux


def rss_bytes() -> int:
    """Current resident set size of this process [bytes] (VmRSS; 0 where unknown)."""
    kib = _status_kib("VmRSS")
    return kib * 1024 if kib is not None else 0


def mib(n_bytes: float) -> float:
    return n_bytes / _MIB


class IsolatedError(RuntimeError):
    """A target run in a child process failed; `str()` is its last error line."""


def run_isolated(target: str, kwargs: Mapping[str, Any], *, timeout_s: float | None = None,
                 env: Mapping[str, str] | None = None, pythonpath: Sequence[str | os.PathLike] = (),
                 keep_compile_cache: bool = False, cpus: Sequence[int] | None = None) -> dict:
    """Run `module:function(**kwargs)` in a fresh Python process; return its result dict.

    The child imports the module, calls the function (which returns a JSON-able dict) and
    adds `peak_rss_bytes` (its own high-water mark, measured after the call) and
    `child_wall_s` (import + call). Its stdout/stderr (e.g. a C++ peer's progress lines) are
    captured and dropped unless it fails.

    Args:
      target: `"package.module:function"`.
      kwargs: JSON-able keyword arguments of the function.
      timeout_s: kill the child after this many seconds (None: no limit).
      env: extra environment variables for the child (e.g. `OMP_NUM_THREADS`).
      pythonpath: folders put in front of the child's `sys.path`.
      keep_compile_cache: keep JAX's persistent compilation cache if the environment enables
        it (default: off in the child, so compile times are cold-start times).
      cpus: pin the child to these CPU ids (`os.sched_setaffinity`, before anything is
        imported; XLA and OpenMP size their thread pools from it) and set `OMP_NUM_THREADS`
        to their number. None: the parent's CPUs and environment.

    Raises:
      IsolatedError: the child exited non-zero, timed out, or returned no result.
    """
    # no gfjax caches from `import gfjax` in the child: JAX's cache only through the
    # environment variables below, when kept
    child_env = dict(os.environ) | {"GFJAX_CACHE": "0"}
    if not keep_compile_cache:
        for key in _CACHE_ENV:
            child_env.pop(key, None)
    if cpus is not None:
        child_env["OMP_NUM_THREADS"] = str(len(cpus))
    child_env.update(env or {})
    with tempfile.TemporaryDirectory(prefix="gfjax-bench-") as tmp:
        out = Path(tmp) / "result.json"
        spec = {"target": target, "kwargs": dict(kwargs), "out": str(out),
                "pythonpath": [os.fspath(p) for p in pythonpath],
                "cpus": None if cpus is None else [int(c) for c in cpus]}
        command = [sys.executable, "-c", "import sys; from gfjax.bench.harness import _child_main; "
                   "sys.exit(_child_main(sys.argv[1]))", json.dumps(spec)]
        try:
            done = subprocess.run(command, env=child_env, capture_output=True, text=True,
                                  timeout=timeout_s, check=False)
        except subprocess.TimeoutExpired:
            raise IsolatedError(f"{target}: no result within {timeout_s:g} s (killed)") from None
        if done.returncode != 0 or not out.exists():
            lines = [ln for ln in (done.stderr or done.stdout or "").splitlines() if ln.strip()]
            last = lines[-1].strip() if lines else f"exit code {done.returncode}, no output"
            raise IsolatedError(f"{target}: {last}")
        return json.loads(out.read_text())


def compile_cache_env(folder: str | os.PathLike) -> dict[str, str]:
    """Environment that makes a child's JAX keep every compiled program in `folder`
    (pass with `keep_compile_cache=True`)."""
    return {"JAX_COMPILATION_CACHE_DIR": os.fspath(folder), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
            "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0"}


def choose_cpus(n_threads: int | None) -> list[int] | None:
    """The first `n_threads` CPUs this process may run on (None for None).

    Raises:
      ValueError: `n_threads` < 1 or more than the CPUs available.
    """
    if n_threads is None:
        return None
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if not 1 <= n_threads <= len(allowed):
        raise ValueError(f"threads must be between 1 and {len(allowed)} (CPUs available), got {n_threads}")
    return allowed[:n_threads]


def _child_main(spec_json: str) -> int:
    """Entry point of the child process of `run_isolated`."""
    spec = json.loads(spec_json)
    if spec.get("cpus") is not None:
        os.sched_setaffinity(0, spec["cpus"])
    sys.path[:0] = spec["pythonpath"]
    watch = Stopwatch()
    module_name, _, function_name = spec["target"].partition(":")
    function = getattr(importlib.import_module(module_name), function_name)
    result = dict(function(**spec["kwargs"]))
    result["peak_rss_bytes"] = peak_rss_bytes()
    result["n_cpus"] = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    result["child_wall_s"] = watch.wall_s
    Path(spec["out"]).write_text(json.dumps(result))
    return 0


__all__ = ["Stopwatch", "Timing", "time_call", "CompileClock", "peak_rss_bytes", "rss_bytes", "mib",
           "IsolatedError", "run_isolated", "choose_cpus", "compile_cache_env", "BACKEND_COMPILE_EVENT"]
