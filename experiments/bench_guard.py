"""`make bench`: the speed regression guard, whole processes as ratios to peers in one run.

    nice .venv/bin/python experiments/bench_guard.py [--cases NAME,...] [--pairs 5]
        [--record] [--slow NAME=FACTOR]

Each case times `gfjax` against a peer in alternated pairs (`gfjax.bench.guard`) on the
forest tile `bcts_2` (823,945 points; ../shared/data or `$GFJAX_SHARED_DATA`) and compares
the ratio of medians with the one recorded in `experiments/results/bench_guard.json`: more
than 15 % above it exits 1. `--record` writes the measured ratios as the new record (after a
change that is meant to move them; say why in the commit). `--slow NAME=FACTOR` makes case
NAME's subject FACTOR times slower (the guard's own check: `--slow smrf/pysmrf=1.2` must
fail). Writes `experiments/results/bench_guard.md` when every case ran and none was slowed.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.common import DATA, RESULTS  # noqa: E402
from experiments.survey_scale import write_survey  # noqa: E402
from gfjax.bench import guard  # noqa: E402
from gfjax.bench.run import machine  # noqa: E402

FILE = DATA / "lasR_bcts" / "bcts_2.laz"
SURVEY_FILES = 4
RECORD = RESULTS / "bench_guard.json"
GFJAX = (sys.executable, "-m", "gfjax.cli.main", "-q")


def cases(scratch: Path) -> list[guard.Case]:
    """The fixed set of `make bench` (files written into `scratch`)."""
    def filter_(method: str, *more: str) -> guard.Side:
        return guard.Side((*GFJAX, "filter", str(FILE), "-o", str(scratch / f"{method}.laz"), "--force",
                           "--method", method, *more))

    tiles = write_survey(scratch, SURVEY_FILES)

    def survey(*more: str) -> guard.Side:
        out = scratch / ("independent" if more else "survey")
        out.mkdir(exist_ok=True)
        return guard.Side((*GFJAX, "filter", *map(str, tiles), "-o", str(out), "--force", "--method", "smrf", *more))

    return [
        guard.Case("smrf/pysmrf", filter_("smrf"), guard.peer("pysmrf", FILE),
                   "a whole `gfjax filter --method smrf` process / pysmrf.classify(windows=18)'s call"),
        guard.Case("dmf/pysmrf", filter_("dmf"), guard.peer("pysmrf", FILE),
                   "a whole `gfjax filter --method dmf` process / pysmrf.classify(windows=18)'s call"),
        guard.Case("csf/CSF", filter_("csf"), guard.peer("cloth-simulation-filter", FILE),
                   "a whole `gfjax filter --method csf` process / the CSF package's call"),
        guard.Case("sparsegf/smrf", filter_("sparsegf"), filter_("smrf"),
                   "whole `gfjax filter` processes, SparseGF / SMRF"),
        guard.Case("vote/smrf", filter_("vote"), filter_("smrf"),
                   "whole `gfjax filter` processes, the vote (the default method) / SMRF"),
        guard.Case("survey/files", survey(), survey("--independent"),
                   f"{SURVEY_FILES} copies of the tile as a survey (out of core) / the same files with "
                   "`--independent`, SMRF, whole processes"),
        guard.Case("first/second", filter_("smrf")._replace(fresh_cache=True), filter_("smrf"),
                   "a first `gfjax filter --method smrf` process (empty caches) / a second one"),
    ]


def markdown(rows: list[dict], command: str, when: dict) -> str:
    lines = ["# Speed regression guard (`make bench`)", "",
             f"Command: `{command}`; {when['nproc']} CPUs, {when['processor']}. Medians of alternated "
             "pairs; a case fails when its ratio is more than 15 % above the recorded one.", "",
             "| case | what | subject s | peer s | ratio | recorded | limit | |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in rows:
        verdict = {True: "ok", False: "**FAIL**", None: "not recorded"}[r["passed"]]
        recorded = "" if r["recorded"] is None else f"{r['recorded']:.3f}"
        limit = "" if r["limit"] is None else f"{r['limit']:.3f}"
        lines.append(f"| {r['name']} | {r['describes']} | {r['subject_s']:.2f} | {r['peer_s']:.2f} | "
                     f"{r['ratio']:.3f} | {recorded} | {limit} | {verdict} ({r['pairs']} pairs) |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=None, help="comma-separated case names (default: all)")
    parser.add_argument("--pairs", type=int, default=guard.PAIRS)
    parser.add_argument("--record", action="store_true", help="write the measured ratios as the record")
    parser.add_argument("--slow", action="append", default=[], metavar="NAME=FACTOR",
                        help="make a case's subject FACTOR times slower (checks the guard)")
    args = parser.parse_args()
    if not FILE.exists():
        raise SystemExit(f"bench_guard: {FILE} not found (set GFJAX_SHARED_DATA to the shared data folder)")
    slow = {name: float(factor) for name, factor in (item.split("=", 1) for item in args.slow)}
    record = json.loads(RECORD.read_text()) if RECORD.exists() else {"ratios": {}}
    scratch = Path(tempfile.mkdtemp(prefix="gfjax-bench-guard-"))
    try:
        chosen = cases(scratch)
        if args.cases:
            names = args.cases.split(",")
            unknown = set(names) - {c.name for c in chosen}
            if unknown:
                raise SystemExit(f"--cases: unknown {', '.join(sorted(unknown))}; "
                                 f"choose from {', '.join(c.name for c in chosen)}")
            chosen = [c for c in chosen if c.name in names]
        for name in set(slow) - {c.name for c in chosen}:
            raise SystemExit(f"--slow: no case {name!r}")
        chosen = [c._replace(subject=guard.slowed(c.subject, slow[c.name])) if c.name in slow else c for c in chosen]

        def report(row):
            verdict = {True: "ok", False: "FAIL", None: "not recorded"}[row["passed"]]
            limit = "" if row["limit"] is None else f" (limit {row['limit']:.3f})"
            print(f"{row['name']:14s} {row['subject_s']:7.2f} s / {row['peer_s']:6.2f} s = {row['ratio']:.3f}{limit} "
                  f"{verdict}", flush=True)

        recorded = {} if args.record else record["ratios"]
        rows = guard.check(chosen, recorded, pairs=args.pairs, report=report)
    except guard.GuardError as err:
        print(f"bench_guard: {err}", file=sys.stderr)
        return 2
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    command = "nice .venv/bin/python experiments/bench_guard.py " + " ".join(sys.argv[1:])
    if args.record:
        measured = {r["name"] for r in rows}
        record = {"ratios": {**record["ratios"], **{r["name"]: round(r["ratio"], 4) for r in rows}},
                  "machine": machine(), "rows": [r for r in record.get("rows", []) if r["name"] not in measured] + rows}
        RECORD.write_text(json.dumps(record, indent=1) + "\n")
    if not slow and not args.cases:
        rows = [dict(r, recorded=record["ratios"].get(r["name"]),
                     limit=record["ratios"][r["name"]] * (1 + guard.TOLERANCE) if r["name"] in record["ratios"] else None,
                     passed=guard.passes(r["ratio"], record["ratios"][r["name"]]) if r["name"] in record["ratios"] else None)
                for r in rows]
        (RESULTS / "bench_guard.md").write_text(markdown(rows, command.strip(), machine()))
    failed = [r["name"] for r in rows if r["passed"] is False]
    if failed:
        print(f"bench_guard: slower than recorded (more than {guard.TOLERANCE:.0%}): {', '.join(failed)}")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
