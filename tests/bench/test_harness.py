"""gfjax.bench.harness: wall times, compile clock, peak RSS of an isolated run (loose bounds)."""
from __future__ import annotations

import textwrap
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax.bench import harness

ALLOC_MIB = 200


def test_time_call_counts_and_measures_a_sleep():
    calls = []

    def nap():
        calls.append(None)
        time.sleep(0.05)
        return len(calls)

    timing, last = harness.time_call(nap, repeat=3, warmup=2)
    assert len(calls) == 5 and last == 5
    assert len(timing.warmup_s) == 2 and len(timing.times_s) == len(timing.cpu_times_s) == 3
    assert all(0.045 <= t < 5.0 for t in (*timing.warmup_s, *timing.times_s))
    assert timing.min_s <= timing.median_s
    assert all(0.0 <= t < 5.0 for t in timing.cpu_times_s)


@pytest.mark.parametrize("repeat, warmup", [(0, 1), (1, -1)])
def test_time_call_rejects_bad_counts(repeat, warmup):
    with pytest.raises(ValueError, match="repeat"):
        harness.time_call(lambda: None, repeat=repeat, warmup=warmup)


def test_time_call_blocks_on_jax_arrays():
    x = jnp.arange(1000, dtype=jnp.float32)
    timing, result = harness.time_call(lambda: jnp.cumsum(x), repeat=1, warmup=1, block=True)
    assert float(result[-1]) == pytest.approx(999 * 1000 / 2)
    assert timing.times_s[0] >= 0.0


def test_compile_clock_sees_a_compile_and_not_a_cached_call():
    @jax.jit
    def poly(v):
        return v * v + jnp.float32(3.0) * v

    x = jnp.ones((7, 13), dtype=jnp.float32)
    with harness.CompileClock() as first:
        poly(x).block_until_ready()
    with harness.CompileClock() as second:
        poly(x).block_until_ready()
    assert first.n_compiles >= 1 and first.compile_s > 0.0
    assert second.n_compiles == 0 and second.compile_s == 0.0


def test_peak_rss_is_at_least_current_rss():
    assert harness.peak_rss_bytes() >= harness.rss_bytes() > 0


@pytest.fixture
def child_module(tmp_path):
    (tmp_path / "bench_child_targets.py").write_text(textwrap.dedent("""
        import time
        import numpy as np
        from gfjax.bench import harness

        def allocate(mib):
            before = harness.rss_bytes()
            block = np.ones(mib * 2**20 // 8, dtype=np.float64)   # touched: resident
            total = float(block.sum())
            del block
            return {"before": before, "total": total}

        def fail():
            raise RuntimeError("target failed on purpose")

        def sleep(seconds):
            time.sleep(seconds)
            return {}
    """))
    return tmp_path


def test_run_isolated_reports_the_childs_own_peak(child_module):
    small = harness.run_isolated("bench_child_targets:allocate", {"mib": 1}, pythonpath=[child_module])
    big = harness.run_isolated("bench_child_targets:allocate", {"mib": ALLOC_MIB}, pythonpath=[child_module])
    assert big["total"] == ALLOC_MIB * 2**20 // 8
    grown_mib = harness.mib(big["peak_rss_bytes"] - big["before"])
    assert 0.75 * ALLOC_MIB <= grown_mib <= 3 * ALLOC_MIB
    # a fresh process: the earlier big allocation does not carry over (nor the parent's peak)
    assert harness.mib(small["peak_rss_bytes"] - small["before"]) < 0.5 * ALLOC_MIB
    assert big["child_wall_s"] > 0.0


def test_run_isolated_failure_and_timeout(child_module):
    with pytest.raises(harness.IsolatedError, match="target failed on purpose"):
        harness.run_isolated("bench_child_targets:fail", {}, pythonpath=[child_module])
    with pytest.raises(harness.IsolatedError, match="no result within"):
        harness.run_isolated("bench_child_targets:sleep", {"seconds": 30}, pythonpath=[child_module],
                             timeout_s=3)


def test_run_isolated_drops_the_persistent_compile_cache(child_module, monkeypatch):
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", "/nonexistent/cache")
    (child_module / "bench_env_target.py").write_text(
        "import os\ndef env():\n    return {'cache': os.environ.get('JAX_COMPILATION_CACHE_DIR'),"
        " 'extra': os.environ.get('BENCH_EXTRA')}\n")
    got = harness.run_isolated("bench_env_target:env", {}, pythonpath=[child_module], env={"BENCH_EXTRA": "1"})
    assert got["cache"] is None and got["extra"] == "1"
    kept = harness.run_isolated("bench_env_target:env", {}, pythonpath=[child_module], keep_compile_cache=True)
    assert kept["cache"] == "/nonexistent/cache"


def test_run_isolated_pins_the_child(child_module):
    (child_module / "bench_cpu_target.py").write_text(
        "import os\ndef cpus():\n"
        "    return {'cpus': sorted(os.sched_getaffinity(0)), 'omp': os.environ.get('OMP_NUM_THREADS')}\n")
    first = harness.choose_cpus(1)
    got = harness.run_isolated("bench_cpu_target:cpus", {}, pythonpath=[child_module], cpus=first)
    assert got["cpus"] == first and got["omp"] == "1" and got["n_cpus"] == 1
    with pytest.raises(ValueError, match="threads must be between 1"):
        harness.choose_cpus(0)
    assert harness.choose_cpus(None) is None


def test_stopwatch_times_a_block_and_stops_at_its_end():
    with harness.Stopwatch() as watch:
        assert watch.running
        time.sleep(0.02)
        so_far = watch.wall_s
    assert not watch.running
    assert 0.015 <= so_far <= watch.wall_s < 5.0
    assert np.isfinite(watch.wall_s)
    assert 0.0 <= watch.cpu_s < 5.0
    stopped = watch.wall_s
    time.sleep(0.01)
    assert watch.wall_s == stopped and watch.stop().wall_s == stopped


def test_stopwatch_counts_cpu_seconds_and_runs_until_stopped():
    watch = harness.Stopwatch()
    # busy for 30 ms of this process's CPU time and of wall time both: another of its threads
    # at work (a test before this one may leave one) adds CPU time faster than the clock runs
    cpu_end, wall_end = time.process_time() + 0.03, time.perf_counter() + 0.03
    while time.process_time() < cpu_end or time.perf_counter() < wall_end:
        pass
    assert watch.running and watch.cpu_s >= 0.025
    watch.stop()
    assert watch.wall_s >= 0.025 and not watch.running
