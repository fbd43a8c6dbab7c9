"""`gfjax bench`: every file x every filter (gfjax methods and peer packages), one table, JSON.

Each (file, filter) pair runs in a fresh process (`harness.run_isolated` of
`job.bench_one`), one after the other, so timings do not overlap and each peak RSS is the
run's own. The records (one dict per pair, `RECORD_KEYS`) are printed as one table, written as
JSON (`document`) and drawn as total error against points per second (`plot`).
"""
from __future__ import annotations

import datetime
import math
import os
import platform
import sys
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

from gfjax.bench import harness, peers
from gfjax.errors import InputError

SCHEMA = "gfjax-bench/1"
RECORD_KEYS = ("file", "filter", "kind", "status", "error", "n_cpus", "n_points", "n_used", "n_ground",
               "first_call_s", "compile_s", "n_compiles", "n_cache_hits", "filter_s", "read_s", "write_s", "job_s",
               "filter_times_s", "job_times_s", "points_per_s", "filter_points_per_s",
               "peak_rss_mib", "baseline_rss_mib", "rss_per_million_points_mib",
               "point_metrics", "dtm_metrics")


class Runner(NamedTuple):
    """One filter of the comparison: a gfjax method or a peer package."""

    kind: str   # "method" or "peer"
    name: str
    model: str | None = None    # SparseGF's model file (None: the shipped model)

    @property
    def label(self) -> str:
        if self.kind == "peer":
            return self.name
        return f"gfjax {self.name}" + (f" ({Path(self.model).name})" if self.model else "")


def plan(methods_text: str | None, peers_text: str | None, *, model: str | None = None
         ) -> tuple[list[Runner], list[str]]:
    """The runners for `--methods` / `--peers`, and one note per peer that is not installed.

    `--methods` None = every available gfjax method (`gfjax.methods.available()`), "none" =
    no method; a named method must exist and be available. `--peers`: see `peers.parse_peers`.
    `model`: SparseGF's model file (`--model`), loaded once here so a bad file fails first.

    Raises:
      InputError: an unknown or unavailable method, an unknown peer, a bad model file or a
        model without SparseGF, or nothing to run.
    """
    from gfjax import methods

    if methods_text is None:
        method_names = methods.available()
    else:
        method_names = list(dict.fromkeys(p.strip() for p in methods_text.split(",") if p.strip()))
        if method_names == ["none"]:
            method_names = []
        for name in method_names:
            if name not in methods.PACKAGES:
                raise InputError(f"--methods: unknown method {name!r}; choose from "
                                 f"{', '.join(methods.names())} (or none)")
            methods.get(name, option="--methods")
    takers = [name for name in method_names if methods.get(name).load_model is not None]
    if model is not None:
        if not takers:
            able = " or ".join(n for n in methods.available() if methods.get(n).load_model is not None)
            raise InputError(f"--model {model}: only the {able} method takes a model; add it to --methods")
        for name in takers:
            methods.get(name).load_model(model)
    runners = [Runner("method", name, model if name in takers else None) for name in method_names]
    notes = []
    for name in peers.parse_peers(peers_text):
        if peers.installed(name):
            runners.append(Runner("peer", name))
        else:
            notes.append(peers.skip_note(name))
    if not runners:
        raise InputError("--methods/--peers: nothing to run (no method, and no installed peer)")
    return runners, notes


def _rates(record: dict) -> None:
    n = record["n_points"]
    record["points_per_s"] = n / record["job_s"] if record["job_s"] > 0 else math.inf
    record["filter_points_per_s"] = n / record["filter_s"] if record["filter_s"] > 0 else math.inf
    peak, base = record.pop("peak_rss_bytes"), record.pop("baseline_rss_bytes")
    record["peak_rss_mib"] = harness.mib(peak)
    record["baseline_rss_mib"] = harness.mib(base)
    record["rss_per_million_points_mib"] = harness.mib(max(peak - base, 0)) * 1e6 / n if n else 0.0


def run_one(path: Path, runner: Runner, *, repeat: int = 1, units: str | None = None,
            timeout_s: float | None = None, env: dict | None = None, threads: int | None = None,
            compile_cache: str | os.PathLike | None = None) -> dict:
    """Benchmark one filter on one file in a fresh process; a record with `RECORD_KEYS`.

    `threads`: run on that many CPUs (`harness.choose_cpus`: affinity and `OMP_NUM_THREADS`),
    the same for every filter; None: every CPU, environment as is. `compile_cache`: a folder
    for JAX's persistent compilation cache shared by the runs (programs compiled for an earlier
    file are loaded, not compiled; `compile_s` is then the compiling this run still did);
    None: every run compiles from scratch. A failure of the filter (an
    exception, a crash, the timeout) gives `status="failed"` and the error's last line in
    `error`, with the other figures None.
    """
    record = dict.fromkeys(RECORD_KEYS)
    record.update(file=str(path), filter=runner.label, kind=runner.kind, status="ok")
    try:
        result = harness.run_isolated("gfjax.bench.job:bench_one",
                                      {"path": str(path), "kind": runner.kind, "name": runner.name,
                                       "repeat": repeat, "units": units, "model": runner.model},
                                      timeout_s=timeout_s, cpus=harness.choose_cpus(threads),
                                      env={**(harness.compile_cache_env(compile_cache) if compile_cache else {}),
                                           **(env or {})},
                                      keep_compile_cache=compile_cache is not None)
    except harness.IsolatedError as err:
        record.update(status="failed", error=str(err))
        return record
    record.update({k: v for k, v in result.items() if k in RECORD_KEYS or k.endswith("rss_bytes")})
    _rates(record)
    return {k: record[k] for k in RECORD_KEYS}


def iter_runs(files: Sequence[Path], runners: Sequence[Runner], *, skip: Iterable[tuple[str, str]] = (),
              **kwargs) -> Iterator[dict]:
    """`run_one` for every (file, runner), file by file; pairs `(str(file), label)` in `skip`
    are left out (to resume an interrupted benchmark)."""
    skip = set(skip)
    for path in files:
        for runner in runners:
            if (str(path), runner.label) not in skip:
                yield run_one(path, runner, **kwargs)


def machine() -> dict:
    """Facts about the machine the benchmark ran on."""
    import jax

    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {"nproc": os.cpu_count(), "affinity_cpus": affinity,
            "loadavg_1_5_15": list(load), "platform": platform.platform(), "processor": cpu_model(),
            "python": platform.python_version(), "jax": jax.__version__, "jax_backend": jax.default_backend(),
            "jax_device": str(jax.devices()[0]),
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS"), "xla_flags": os.environ.get("XLA_FLAGS")}


def cpu_model() -> str:
    """The CPU's model name (`/proc/cpuinfo`), else `platform.processor()`."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def document(records: list[dict], *, repeat: int, notes: Sequence[str], command: str,
             threads: int | None = None, compile_cache: bool = False) -> dict:
    """The JSON document of a benchmark (schema `SCHEMA`)."""
    from gfjax import __version__

    return {"schema": SCHEMA, "gfjax_version": __version__, "command": command,
            "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "machine": machine(), "repeat": repeat, "threads": threads,
            "compile_cache": compile_cache, "dtm_cell_m": 2.0, "notes": list(notes),
            "runs": records, "summary": summarize(records)}


def summarize(records: Sequence[dict]) -> list[dict]:
    """Per filter: unweighted means over labelled files it ran on, pooled throughput, peak RSS."""
    import numpy as np

    rows = []
    for label in dict.fromkeys(r["filter"] for r in records):
        ok = [r for r in records if r["filter"] == label and r["status"] == "ok"]
        scored = [r for r in ok if r["point_metrics"] is not None]
        mean = {key: (float(np.mean([r["point_metrics"][key] for r in scored])) if scored else None)
                for key in ("total_error", "type1", "type2", "kappa", "f1")}
        rmse = [r["dtm_metrics"]["rmse_m"] for r in scored]
        points, job_s = sum(r["n_points"] for r in ok), sum(r["job_s"] for r in ok)
        rows.append({"filter": label, "n_files": len(ok), "n_labelled": len(scored),
                     "n_failed": sum(r["status"] != "ok" for r in records if r["filter"] == label),
                     **{f"mean_{k}": v for k, v in mean.items()},
                     "mean_dtm_rmse_m": float(np.mean(rmse)) if rmse else None,
                     "points_per_s": points / job_s if job_s > 0 else None,
                     "max_peak_rss_mib": max((r["peak_rss_mib"] for r in ok), default=None)})
    return rows


def _pct(value) -> str:
    return "-" if value is None else f"{100.0 * value:.2f}"


def _num(value, fmt: str) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, fmt)


def _aligned(header: list[str], body: list[list[str]], *, left: int = 2) -> str:
    widths = [max(len(row[i]) for row in [header, *body]) for i in range(len(header))]
    lines = ["  ".join(c.ljust(widths[i]) if i < left else c.rjust(widths[i]) for i, c in enumerate(row))
             for row in [header, *body]]
    lines.insert(1, "-" * len(lines[0]))
    return "\n".join(lines)


TABLE_HEADER = ["file", "filter", "points", "filter s", "compile s", "job s", "points/s", "peak MiB",
                "total err %", "type I %", "type II %", "kappa", "F1", "DTM RMSE m"]
SUMMARY_HEADER = ["filter", "files", "labelled", "mean total err %", "mean type I %", "mean type II %",
                  "mean kappa", "mean DTM RMSE m", "points/s (pooled)", "max peak MiB"]


def table_rows(records: Sequence[dict]) -> tuple[list[list[str]], list[str]]:
    """Cells of `TABLE_HEADER` for each record, and one line per failed run."""
    body, failures = [], []
    for r in records:
        name = Path(r["file"]).name
        if r["status"] != "ok":
            body.append([name, r["filter"], "failed", *["-"] * (len(TABLE_HEADER) - 3)])
            failures.append(f"failed: {name}, {r['filter']}: {r['error']}")
            continue
        pm, dm = r["point_metrics"] or {}, r["dtm_metrics"] or {}
        body.append([name, r["filter"], f"{r['n_points']:,}", f"{r['filter_s']:.2f}", _num(r["compile_s"], ".2f"),
                     f"{r['job_s']:.2f}", f"{r['points_per_s']:,.0f}", f"{r['peak_rss_mib']:.0f}",
                     _pct(pm.get("total_error")), _pct(pm.get("type1")), _pct(pm.get("type2")),
                     _num(pm.get("kappa"), ".4f"), _num(pm.get("f1"), ".4f"), _num(dm.get("rmse_m"), ".3f")])
    return body, failures


def summary_rows(summary: Sequence[dict]) -> list[list[str]]:
    """Cells of `SUMMARY_HEADER` for each row of `summarize`."""
    return [[s["filter"], str(s["n_files"]), str(s["n_labelled"]), _pct(s["mean_total_error"]),
             _pct(s["mean_type1"]), _pct(s["mean_type2"]), _num(s["mean_kappa"], ".4f"),
             _num(s["mean_dtm_rmse_m"], ".3f"), _num(s["points_per_s"], ",.0f"), _num(s["max_peak_rss_mib"], ".0f")]
            for s in summary]


def format_table(records: Sequence[dict]) -> str:
    """One row per (file, filter): times, throughput, memory and accuracy (percent)."""
    body, failures = table_rows(records)
    return "\n".join([_aligned(TABLE_HEADER, body), *failures])


def format_summary(summary: Sequence[dict]) -> str:
    """Per filter: mean accuracy over its labelled files (unweighted), pooled points/s."""
    return _aligned(SUMMARY_HEADER, summary_rows(summary), left=1)


def markdown(header: Sequence[str], body: Sequence[Sequence[str]], *, left: int = 2) -> str:
    """A Markdown table; columns after the first `left` are right-aligned."""
    rule = ["---" if i < left else "---:" for i in range(len(header))]
    return "\n".join("| " + " | ".join(row) + " |" for row in [header, rule, *body])


def has_accuracy(records: Sequence[dict]) -> bool:
    """True when some run succeeded on a labelled file (so `plot` has something to draw)."""
    return any(r["status"] == "ok" and r["point_metrics"] is not None for r in records)


def json_safe(value):
    """`value` with every non-finite float replaced by None (strict JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def plot(records: Sequence[dict], path: Path, *, title: str = "gfjax bench") -> bool:
    """Total error [%] against whole-job points per second (log), one colour per filter.

    Small markers: one file each; large marker: the filter's unweighted mean total error
    over its labelled files at its pooled throughput. Returns False (nothing drawn) when no
    run has accuracy figures.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not has_accuracy(records):
        return False
    scored = [r for r in records if r["status"] == "ok" and r["point_metrics"] is not None]
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=120)
    for i, label in enumerate(dict.fromkeys(r["filter"] for r in scored)):
        mine = [r for r in scored if r["filter"] == label]
        colour = f"C{i % 10}"
        ax.scatter([r["points_per_s"] for r in mine], [100 * r["point_metrics"]["total_error"] for r in mine],
                   s=14, color=colour, alpha=0.45)
        pooled = sum(r["n_points"] for r in mine) / sum(r["job_s"] for r in mine)
        mean_err = 100 * sum(r["point_metrics"]["total_error"] for r in mine) / len(mine)
        ax.scatter([pooled], [mean_err], s=90, color=colour, edgecolor="black", label=f"{label} ({len(mine)} files)")
    ax.set_xscale("log")
    ax.set_xlabel("whole-job throughput (read + filter + write) [points/s]")
    ax.set_ylabel("total error [%]")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, format="png")        # a PNG whatever the name (atomic writes use temporary names)
    plt.close(fig)
    return True


def command_line() -> str:
    return " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])


__all__ = ["SCHEMA", "RECORD_KEYS", "Runner", "plan", "run_one", "iter_runs", "machine", "document",
           "summarize", "TABLE_HEADER", "SUMMARY_HEADER", "table_rows", "summary_rows", "format_table",
           "format_summary", "markdown", "has_accuracy", "json_safe", "plot"]
