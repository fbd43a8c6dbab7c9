"""One benchmark run: one file, one filter (a gfjax method or a peer), in its own process.

`bench_one` is the target `gfjax.bench.run` hands to `harness.run_isolated`, so each run's
peak memory is its own. Protocol (STYLE.md "Benchmarks"):

1. import the filter; note the resident memory (`baseline_rss_bytes`);
2. warm-up: read the file, filter it once (`first_call_s`; JAX compile time apart,
   `compile_s`, from `harness.CompileClock`);
3. `repeat` whole jobs, each timed in parts: read (`read_s`), filter (`filter_s`), write the
   classified file to a temporary folder (`write_s`); `job_s` is their sum. Medians are
   reported, every time is kept;
4. accuracy of the last job's labels where the file has reference labels (class 2 present):
   point metrics on the scored points (`gfjax.metrics.scored_mask`: noise 7/18, water 9 and
   overlap 12 left out), DTM metrics at 2 m (`gfjax.metrics`, SPEC section 8). Reference
   ground is class 2; every other scored class (ISPRS class 0, vendor class 1) is non-ground.

gfjax methods get the `Cloud` and use their defaults (`returns="all"`); peers get the used
points in metres (`cloud.xyz_m[cloud.filter_mask()]`), and that conversion counts as part of
their filter time, as it does inside gfjax's `filter`.
"""
from __future__ import annotations

import statistics
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gfjax.bench import harness

DTM_CELL_M = 2.0


def _filter_function(kind: str, name: str, model: str | None = None) -> Callable:
    """`cloud -> ground bool (n,)` for a gfjax method or a peer (imports it now); `model`:
    SparseGF's model file (None: the shipped one)."""
    if kind == "method":
        from gfjax import methods

        method = methods.get(name)
        options = {}
        if method.load_model is not None:
            loaded, config = method.load_model(model)
            options = {"model": loaded, "config": config}

        def run_method(cloud) -> np.ndarray:
            return np.asarray(method.filter(cloud, progress=False, **options).ground, dtype=bool)

        return run_method
    if kind == "peer":
        import importlib

        from gfjax.bench.peers import PEERS

        peer = PEERS[name]
        importlib.import_module(peer.module)

        def run_peer(cloud) -> np.ndarray:
            use = cloud.filter_mask()
            ground = np.zeros(cloud.n_points, dtype=bool)
            ground[use] = peer.run(cloud.xyz_m[use])
            return ground

        return run_peer
    raise ValueError(f"kind must be 'method' or 'peer', got {kind!r}")


def _accuracy(cloud, ground: np.ndarray) -> tuple[dict | None, dict | None]:
    from gfjax import metrics

    reference = cloud.classification == np.uint8(2)
    if not np.any(reference):
        return None, None
    scored = metrics.scored_mask(cloud.classification)
    return (metrics.point_metrics(ground, reference, mask=scored),
            metrics.dtm_metrics(cloud.xyz_m, ground, reference, cell_m=DTM_CELL_M, mask=scored))


def _timed(fn: Callable, *args, **kwargs):
    with harness.Stopwatch() as watch:
        value = fn(*args, **kwargs)
    return value, watch.wall_s


def bench_one(*, path: str, kind: str, name: str, repeat: int = 1, units: str | None = None,
              model: str | None = None) -> dict:
    """Time and score one filter on one file (in the calling process).

    Args:
      path: LAS/LAZ file.
      kind: "method" (a `gfjax.methods` name) or "peer" (a `gfjax.bench.peers.PEERS` name).
      name: the method or peer.
      repeat: timed whole jobs after the warm-up (>= 1).
      units: `--units` override ("m", "ft", "us-ft"), or None for the file's CRS.
      model: SparseGF's model file (None: the model shipped in gfjax).

    Returns:
      JSON-able dict: `n_points`, `n_used`, `n_ground`, `baseline_rss_bytes`, `first_read_s`,
      `first_call_s`, `compile_s` / `trace_lower_s` / `n_compiles` / `n_cache_hits` (None for peers), lists
      `read_times_s`, `filter_times_s`, `write_times_s`, `job_times_s`, their medians
      `read_s`, `filter_s`, `write_s`, `job_s`, and `point_metrics` / `dtm_metrics` (None
      for an unlabelled file). Times in seconds.
    """
    from gfjax.io import las as las_io

    if repeat < 1:
        raise ValueError(f"repeat must be >= 1, got {repeat}")
    run = _filter_function(kind, name, model)
    out: dict = {"baseline_rss_bytes": harness.rss_bytes()}
    cloud, out["first_read_s"] = _timed(las_io.read, path, units=units)
    if kind == "method":
        with harness.CompileClock() as clock:
            ground, out["first_call_s"] = _timed(run, cloud)
        out.update(compile_s=clock.compile_s, trace_lower_s=clock.trace_lower_s, n_compiles=clock.n_compiles,
                   n_cache_hits=clock.n_cache_hits)
    else:
        ground, out["first_call_s"] = _timed(run, cloud)
        out.update(compile_s=None, trace_lower_s=None, n_compiles=None, n_cache_hits=None)
    times: dict[str, list[float]] = {"read": [], "filter": [], "write": [], "job": []}
    with tempfile.TemporaryDirectory(prefix="gfjax-bench-out-") as tmp:
        target = Path(tmp) / f"out{Path(path).suffix.lower() or '.laz'}"
        for _ in range(repeat):
            with harness.Stopwatch() as job:
                cloud, read_s = _timed(las_io.read, path, units=units)
                ground, filter_s = _timed(run, cloud)
                _, write_s = _timed(las_io.write, cloud.with_ground(ground), target, force=True)
            times["job"].append(job.wall_s)
            times["read"].append(read_s)
            times["filter"].append(filter_s)
            times["write"].append(write_s)
    for key, values in times.items():
        out[f"{key}_times_s"] = values
        out[f"{key}_s"] = statistics.median(values)
    out["n_points"] = cloud.n_points
    out["n_used"] = int(np.count_nonzero(cloud.filter_mask()))
    out["n_ground"] = int(np.count_nonzero(ground))
    out["point_metrics"], out["dtm_metrics"] = _accuracy(cloud, ground)
    return out


__all__ = ["bench_one", "DTM_CELL_M"]
