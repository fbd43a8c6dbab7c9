"""The full `gfjax bench` table: every shared data file x every gfjax method and both peers.

One run of `gfjax.bench.run` (each (file, filter) pair in a fresh process, one after another):
filter time, whole-job points per second, peak RSS, and accuracy where the file has reference
labels. Results are saved after every pair, so an interrupted run resumes where it stopped
(pairs already in the JSON are skipped; `--fresh` starts over, `--retry-failed` reruns
failures). At the end (and after every pair) the Markdown report and the plot are rewritten
from the JSON.

Usage:
  nice .venv/bin/python experiments/bench_all.py [--files NAME_OR_GLOB ...] [--methods smrf,...]
      [--peers cloth-simulation-filter,pysmrf] [--repeat 1] [--timeout 900] [--fresh]

`--files` takes paths relative to the data folder (`../shared/data`, or `$GFJAX_SHARED_DATA`),
names or globs (`'isprs_filtertest/reference/*'`, `bcts_1.laz`). Writes
`experiments/results/bench_all.{json,md,png}`.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import tempfile
import time
from pathlib import Path

from gfjax.bench import run as bench

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data")).resolve()
RESULTS = ROOT / "experiments" / "results"
# Labelled files first (ISPRS reference, then vendor-labelled, small to large), sites last.
GROUPS = {
    "ISPRS reference samples (manual labels)": sorted((DATA / "isprs_filtertest" / "reference").glob("samp*-utm.laz")),
    "vendor-labelled tiles (weaker truth)": [DATA / "lidR_topography" / "Topography.laz",
                                             DATA / "pdal_autzen" / "autzen_trim.laz",
                                             DATA / "lasR_bcts" / "bcts_1.laz", DATA / "lasR_bcts" / "bcts_2.laz"],
    "ISPRS full sites (unlabelled, speed only)": sorted((DATA / "isprs_filtertest" / "sites").glob("*.laz")),
}
ALL_FILES = [p for files in GROUPS.values() for p in files]


def select_files(patterns: list[str] | None) -> list[Path]:
    if not patterns:
        return ALL_FILES
    chosen = []
    for pattern in patterns:
        hits = [p for p in ALL_FILES if p.match(pattern) or p.name == pattern
                or p.relative_to(DATA).match(pattern)]
        if not hits:
            raise SystemExit(f"--files {pattern}: matches none of the {len(ALL_FILES)} data files")
        chosen.extend(h for h in hits if h not in chosen)
    return [p for p in ALL_FILES if p in chosen]


def _load(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.exists() else None


def _save_json(path: Path, document: dict) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(bench.json_safe(document), indent=2, allow_nan=False) + "\n")
    tmp.replace(path)


def _md_table(records: list[dict]) -> str:
    body, failures = bench.table_rows(records)
    notes = [""] + [f"- {f}" for f in failures] if failures else []
    return "\n".join([bench.markdown(bench.TABLE_HEADER, body), *notes])


def _md_summary(summary: list[dict]) -> str:
    return bench.markdown(bench.SUMMARY_HEADER, bench.summary_rows(summary), left=1)


def write_report(document: dict, md_path: Path, png_path: Path, *, planned: int) -> None:
    records = document["runs"]
    by_file = {str(p) for p in ALL_FILES}
    done_pairs = len(records)
    partial = done_pairs < planned
    machine = document["machine"]
    lines = [f"# gfjax bench: every method and peer on the shared data{' (PARTIAL)' if partial else ''}", ""]
    if partial:
        lines += [f"**Partial**: {done_pairs} of {planned} planned (file, filter) runs are in this table; "
                  "the missing ones are listed at the end.", ""]
    cache_note = ("with JAX's persistent compilation cache shared by the runs of this benchmark: a "
                  "program compiled for an earlier file of the same shapes is loaded, so `compile s` is the "
                  "compiling that run still had to do (the first file of each shape pays)"
                  if document.get("compile_cache") else "cold: every run compiles from scratch")
    lines += ["Command (resumable; each (file, filter) pair in a fresh process, one after another):", "",
              *[f"    {c}" for c in document.get("invocations", [document["command"]])], "",
              f"Machine: {machine['nproc']} CPUs ({machine['processor']}), {machine['platform']}, Python "
              f"{machine['python']}, JAX {machine['jax']} ({machine['jax_backend']}), OMP_NUM_THREADS="
              f"{machine['omp_num_threads']}. Load average (1/5/15 min) at the start "
              f"{', '.join(f'{x:.1f}' for x in machine['loadavg_1_5_15'])}, at the last update "
              f"{', '.join(f'{x:.1f}' for x in document.get('loadavg_end', machine['loadavg_1_5_15']))}: "
              "the machine was shared with other jobs, so times are upper bounds and noisy.", "",
              f"Protocol: per pair, one warm-up (read + filter; JAX compile time measured apart, {cache_note}), "
              f"then {document['repeat']} timed whole job(s) (read + filter + write LAZ/LAS to a "
              "temporary folder); medians. Threads: every run pinned to "
              f"{document.get('threads') or 'all'} CPU(s) (affinity and OMP_NUM_THREADS), the same for every filter. "
              "`points/s` = points / whole-job time. `peak MiB` = peak RSS of "
              "the run's process (includes the Python/JAX runtime and compilation). Accuracy: ground = "
              "class 2, everything else non-ground (ISPRS: class 0; Topography water, class 9, counts as "
              "non-ground); scored on non-noise, non-withheld points; DTM RMSE of 2 m cell-mean DTMs "
              "(`gfjax.metrics`). gfjax methods and peers with their published defaults. Peers: "
              + "; ".join(document["notes"] or ["both installed"]) + ".", ""]
    for group, files in GROUPS.items():
        names = {str(p) for p in files}
        rows = [r for r in records if r["file"] in names]
        if not rows:
            continue
        lines += [f"## {group}", "", _md_table(rows), ""]
        if any(r["point_metrics"] for r in rows):
            lines += ["Per filter, unweighted mean over these files:", "", _md_summary(bench.summarize(rows)), ""]
    other = [r for r in records if r["file"] not in by_file]
    if other:
        lines += ["## other files", "", _md_table(other), ""]
    if bench.plot([r for r in records if r["file"] in {str(p) for p in GROUPS[next(iter(GROUPS))]}], png_path,
                  title="ISPRS reference samples: total error vs whole-job throughput"):
        lines += [f"![accuracy vs throughput]({png_path.name})", "",
                  "Plot: ISPRS reference samples only; small markers one sample each, large marker the "
                  "filter's unweighted mean total error at its pooled throughput.", ""]
    if partial:
        done = {(r["file"], r["filter"]) for r in records}
        missing: dict[str, list[str]] = {}
        for f, label in document.get("planned", []):
            if (f, label) not in done:
                missing.setdefault(Path(f).name, []).append(label)
        lines += ["## Not run (the time ran out before these pairs)", "",
                  *[f"- {name}: {', '.join(labels)}" for name, labels in missing.items()], ""]
    md_path.write_text("\n".join(lines))


def _filter_rank(label: str) -> int:
    from gfjax.bench.peers import PEERS
    from gfjax.methods import METHODS

    labels = [f"gfjax {m}" for m in METHODS] + list(PEERS)
    return labels.index(label) if label in labels else len(labels)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", nargs="+", default=None, metavar="NAME_OR_GLOB")
    parser.add_argument("--methods", default=None, help="default: every available gfjax method")
    parser.add_argument("--peers", default=None, help="default: both peers (skipped when not installed)")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--threads", type=int, default=1,
                        help="CPUs per run, the same for every filter (0: all CPUs, environment as is)")
    parser.add_argument("--cold", action="store_true",
                        help="no shared JAX compilation cache (every run compiles from scratch)")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per (file, filter) run")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_all.json")
    parser.add_argument("--fresh", action="store_true", help="ignore results already in --out")
    parser.add_argument("--retry-failed", action="store_true", help="rerun pairs that failed before")
    args = parser.parse_args(argv)

    files = select_files(args.files)
    runners, notes = bench.plan(args.methods, args.peers)
    for note in notes:
        print(note, file=sys.stderr)
    previous = None if args.fresh else _load(args.out)
    records = [r for r in (previous or {}).get("runs", [])
               if not (args.retry_failed and r["status"] != "ok")]
    command = "nice " + " ".join(shlex.quote(a) for a in [".venv/bin/python", "experiments/bench_all.py",
                                                          *(sys.argv[1:] if argv is None else argv)])
    threads = args.threads or None
    cache = None if args.cold else Path(tempfile.gettempdir()) / "gfjax_bench_all_jax_cache"
    document = bench.document(records, repeat=args.repeat, notes=notes, command=command, threads=threads,
                              compile_cache=cache is not None)
    document["invocations"] = [*(previous or {}).get("invocations", []), command]
    if previous and records:
        document["machine"] = previous["machine"]       # the load when the run began
        document["created_utc"] = previous["created_utc"]
    planned = {(r["file"], r["filter"]) for r in records}      # the full table: every file x filter
    planned |= {(str(p), r.label) for p in ALL_FILES for r in bench.plan(None, None)[0]}
    planned |= {(str(p), r.label) for p in files for r in runners}
    order = {str(p): i for i, p in enumerate(ALL_FILES)}
    document["planned"] = sorted(planned, key=lambda fr: (order.get(fr[0], len(order)), _filter_rank(fr[1])))
    md_path, png_path = args.out.with_suffix(".md"), args.out.with_suffix(".png")
    done = {(r["file"], r["filter"]) for r in records}
    for record in bench.iter_runs(files, runners, skip=done, repeat=args.repeat,
                                  timeout_s=args.timeout, threads=threads, compile_cache=cache):
        records.append(record)
        records.sort(key=lambda r: (order.get(r["file"], len(order)), _filter_rank(r["filter"])))
        status = (f"{record['points_per_s']:,.0f} points/s" if record["status"] == "ok"
                  else f"FAILED: {record['error']}")
        print(f"{time.strftime('%H:%M:%S')} {Path(record['file']).name} {record['filter']}: {status}", flush=True)
        document.update(runs=records, summary=bench.summarize(records), loadavg_end=list(os.getloadavg()))
        _save_json(args.out, document)
        write_report(document, md_path, png_path, planned=len(planned))
    document.update(runs=records, summary=bench.summarize(records), loadavg_end=list(os.getloadavg()))
    _save_json(args.out, document)
    write_report(document, md_path, png_path, planned=len(planned))
    print(bench.format_table(records))
    return 0


if __name__ == "__main__":
    sys.exit(main())
