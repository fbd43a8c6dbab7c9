"""What the ISPRS accuracy experiments share: the sample files, a first-and-warm call, scoring.

    from experiments.common import ISPRS_REFERENCE, isprs_samples, first_and_again, score
    for path in isprs_samples():
        cloud = gfjax.read(path)
        first_s, again_s, result = first_and_again(lambda: gfjax.smrf.filter(cloud))
        m = score(result.ground, cloud)

The labelled data are not shipped (README, "Data": where each file comes from and how to get
it): they are read from `$GFJAX_SHARED_DATA`, by default `../shared/data` beside the
repository. ISPRS reference ground is ASPRS class 2, every other class non-ground.
Scores are those of `gfjax.metrics.point_metrics` (SPEC section 8).
"""
from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

from gfjax.io.cloud import Cloud
from gfjax.metrics import point_metrics

__all__ = ["ROOT", "DATA", "ISPRS_REFERENCE", "RESULTS", "KEYS", "isprs_samples", "files_parser",
           "first_and_again", "median_time", "score", "write_json", "write_markdown"]

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data"))
ISPRS_REFERENCE = DATA / "isprs_filtertest" / "reference"
RESULTS = ROOT / "experiments" / "results"
KEYS = ("total_error", "type1", "type2", "kappa")        # the per-sample scores the tables report

T = TypeVar("T")


def isprs_samples(folder: Path = ISPRS_REFERENCE) -> list[Path]:
    """The ISPRS reference samples `samp*-utm.laz` of `folder`, sorted (11 in the shared data;
    an empty list when the folder is absent)."""
    return sorted(Path(folder).glob("samp*-utm.laz"))


def files_parser(doc: str, default_files: list[Path], json_name: str) -> argparse.ArgumentParser:
    """The command line of a per-file experiment: `[FILES...] [--json OUT]`, described by the
    first line of `doc`, OUT defaulting to `experiments/results/<json_name>`."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path, default=default_files)
    parser.add_argument("--json", type=Path, default=RESULTS / json_name)
    return parser


def write_json(path: Path, environment: dict, summary: dict, rows: list[dict]) -> None:
    """Write `{"environment", "summary", "files"}` as indented JSON to `path` (folders made)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"environment": environment, "summary": summary, "files": rows}, indent=1))


def write_markdown(path: Path, lines: list[str]) -> None:
    """Write a results report (one line per item) to `path` (folders made) and say so."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path}")


def first_and_again(fn: Callable[[], T]) -> tuple[float, float, T, T]:
    """Call `fn` twice: `(first_s, again_s, first, again)`, wall-clock seconds of each call
    (`time.perf_counter`); the first includes JIT compilation, the second runs warm."""
    start = time.perf_counter()
    first = fn()
    first_s = time.perf_counter() - start
    start = time.perf_counter()
    again = fn()
    again_s = time.perf_counter() - start
    return first_s, again_s, first, again


def score(ground: np.ndarray, cloud: Cloud, mask: np.ndarray | None = None) -> dict:
    """`point_metrics` of bool `(n,)` ground labels against the cloud's class 2, on `mask`
    (bool `(n,)`, default all points)."""
    return point_metrics(ground, cloud.classification == 2, mask=mask)


def median_time(fn: Callable, *args, repeats: int) -> float:
    """Median wall time [s] of `repeats` calls `fn(*args)` after one warm-up call (compiles
    apart), each waited for (`jax.block_until_ready`)."""
    import jax

    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return float(np.median(times))
