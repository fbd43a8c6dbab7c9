"""Where the test suite's time goes: each test's wall time beside JAX's compile times in it.

As a pytest plugin (each worker process appends a line a test to `$SUITE_TIME_OUT.<pid>.tsv`):

    PYTHONPATH=experiments SUITE_TIME_OUT=/tmp/suite .venv/bin/python -m pytest -n 2 -q -p suite_time

then the summary, by test and by test function (parameters summed):

    .venv/bin/python experiments/suite_time.py /tmp/suite [--top 30]

Columns: wall [s] of the test (setup, call and teardown), XLA's backend compile, tracing to a
jaxpr, lowering to MLIR, and reads of JAX's persistent compilation cache, all [s] and summed
over the test's own process. Subprocesses the test starts (the command line, warm-ups,
notebooks' kernels) count in its wall time only.
"""
from __future__ import annotations

import argparse
import collections
import glob
import os
import time

import pytest

EVENTS = {"compile": "/jax/core/compile/backend_compile_duration",
          "trace": "/jax/core/compile/jaxpr_trace_duration",
          "lower": "/jax/core/compile/jaxpr_to_mlir_module_duration",
          "cache_read": "/jax/compilation_cache/cache_retrieval_time_sec"}
_seconds: dict[str, float] = collections.defaultdict(float)


def _listener(event: str, duration_secs: float, **_) -> None:
    _seconds[event] += duration_secs


def pytest_configure(config) -> None:
    import jax.monitoring

    jax.monitoring.register_event_duration_secs_listener(_listener)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _seconds.clear()
    start = time.perf_counter()
    yield
    wall = time.perf_counter() - start
    out = os.environ.get("SUITE_TIME_OUT", "suite_time")
    with open(f"{out}.{os.getpid()}.tsv", "a") as f:
        f.write("\t".join([item.nodeid, f"{wall:.2f}", *(f"{_seconds[e]:.2f}" for e in EVENTS.values())]) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", help="the SUITE_TIME_OUT the run wrote under")
    parser.add_argument("--top", type=int, default=30)
    args = parser.parse_args()
    rows = [line.rstrip("\n").split("\t") for path in glob.glob(f"{args.out}.*.tsv") for line in open(path)]
    names = ["wall", *EVENTS]
    totals = [sum(float(row[k + 1]) for row in rows) for k in range(len(names))]
    print(f"{len(rows)} tests; " + ", ".join(f"{n} {t:.0f} s" for n, t in zip(names, totals)))
    by_function: dict[str, list[float]] = collections.defaultdict(lambda: [0.0] * (len(names) + 1))
    for row in rows:
        sums = by_function[row[0].split("[")[0]]
        sums[0] += 1
        for k in range(len(names)):
            sums[k + 1] += float(row[k + 1])
    header = " ".join(f"{n:>10}" for n in names)
    print(f"\nslowest tests\n{header}  test")
    for row in sorted(rows, key=lambda r: -float(r[1]))[:args.top]:
        print(" ".join(f"{float(v):10.1f}" for v in row[1:]) + f"  {row[0]}")
    print(f"\nslowest test functions, parameters summed\n{header}  tests  function")
    for name, sums in sorted(by_function.items(), key=lambda kv: -kv[1][1])[:args.top]:
        print(" ".join(f"{v:10.1f}" for v in sums[1:]) + f"  {int(sums[0]):5d}  {name}")


if __name__ == "__main__":
    main()
