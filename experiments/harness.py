"""A small reusable timing harness for gfjax benchmarks (`experiments/*_speed.py`, `gfjax bench`).

    from experiments.harness import timed, peak_rss_mb, environment, run_pysmrf, run_csf
    seconds, result = timed(lambda: gfjax.dmf.filter(cloud))

Conventions (STYLE.md, "Benchmarks"): wall-clock seconds from `time.perf_counter`; JAX outputs
are waited for (`block_until_ready`) before the clock stops; the first call of a jitted
function includes compilation, so benchmarks report a warm call and the first call apart.
Peak RSS is the process high-water mark (`getrusage`), so measure gfjax before the peers.
"""
from __future__ import annotations

import os
import platform
import resource
import sys
import time
from typing import Any, Callable, NamedTuple

import numpy as np

__all__ = ["Timing", "timed", "time_repeated", "peak_rss_mb", "environment", "run_pysmrf", "run_csf"]


class Timing(NamedTuple):
    """`seconds` of one call and the throughput over `n_points`."""

    name: str
    seconds: float
    n_points: int

    @property
    def points_per_s(self) -> float:
        return self.n_points / self.seconds if self.seconds > 0 else float("inf")


def _block(value: Any) -> Any:
    try:
        import jax
        return jax.block_until_ready(value)
    except (ImportError, TypeError):
        return value


def timed(fn: Callable[[], Any]) -> tuple[float, Any]:
    """Run `fn()` once; returns `(seconds, result)` with JAX results waited for."""
    start = time.perf_counter()
    out = _block(fn())
    return time.perf_counter() - start, out


def time_repeated(fn: Callable[[], Any], *, repeat: int = 3) -> tuple[float, float, Any]:
    """First call (compile included) and the best of `repeat` warm calls: `(first_s, best_s, result)`."""
    first, out = timed(fn)
    best = min(timed(fn)[0] for _ in range(max(repeat, 0))) if repeat else first
    return first, best, out


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far [MiB] (Linux reports KiB, macOS bytes)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / (1024 * 1024) if sys.platform == "darwin" else rss / 1024


def environment() -> dict:
    """What the figures were measured on."""
    import jax
    return {"python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count(),
            "load_avg_1min": os.getloadavg()[0], "jax": jax.__version__, "device": str(jax.devices()[0]),
            "platform": platform.platform()}


def run_pysmrf(xyz_m: np.ndarray, *, windows: int = 18) -> tuple[float, np.ndarray]:
    """`pysmrf.classify(x, y, z, windows=windows)` with its other defaults: `(seconds, ground)`."""
    import pysmrf
    seconds, res = timed(lambda: pysmrf.classify(xyz_m[:, 0], xyz_m[:, 1], xyz_m[:, 2], windows=windows))
    return seconds, np.asarray(res.is_ground, bool)


def run_csf(xyz_m: np.ndarray) -> tuple[float, np.ndarray]:
    """`cloth-simulation-filter` with its defaults (no cloth export): `(seconds, ground)`."""
    import CSF

    def call():
        csf = CSF.CSF()
        csf.setPointCloud(np.ascontiguousarray(xyz_m, dtype=np.float64))
        ground, off = CSF.VecInt(), CSF.VecInt()
        csf.do_filtering(ground, off, exportCloth=False)
        return np.asarray(ground, dtype=np.int64)

    seconds, idx = timed(call)
    mask = np.zeros(len(xyz_m), bool)
    mask[idx] = True
    return seconds, mask
