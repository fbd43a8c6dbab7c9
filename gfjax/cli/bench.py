"""`gfjax bench FILES...`: every gfjax method and every installed peer package on the same files.

For each file and each filter: filter time (median of `--repeat` runs after one warm-up; JAX
compile time apart), whole-job throughput (read + filter + write, points per second), peak
memory (each run in a fresh process), and, where the file holds reference labels (class 2
present; everything else is non-ground): total error, type I/II, kappa, F-score and the RMSE
of 2 m cell-mean DTMs. gfjax methods get the file's cloud, peers its points in metres; all
use their published defaults.

Peers (`cloth-simulation-filter`, `pysmrf`) are the optional extra `pip install -e '.[bench]'`;
one that is not installed is skipped with a one-line note. Exit codes: 0 all runs succeeded,
1 a filter failed on a file (its row says why; the table and JSON are still written), 2 bad
input or option.
"""
from __future__ import annotations

import argparse
import json
import sys


def add_parser(subparsers) -> argparse.ArgumentParser:
    from gfjax.bench.peers import PEERS
    from gfjax.cli._common import add_model_option, add_units_option, positive_int, ranged
    from gfjax.methods import names

    parser = subparsers.add_parser("bench", help="compare the speed and accuracy of methods and peers",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="FILE", help="LAS/LAZ files, folders or globs")
    parser.add_argument("--methods", default=None, metavar="NAME,...",
                        help=f"gfjax methods, comma-separated ({', '.join(names())}), or none "
                             "(default: every available method)")
    parser.add_argument("--peers", default=None, metavar="NAME,...",
                        help=f"peer packages, comma-separated ({', '.join(PEERS)}), or none "
                             "(default: every installed peer)")
    parser.add_argument("--repeat", type=ranged("--repeat"), default=1, metavar="N",
                        help="timed whole jobs per (file, filter) after the warm-up (default 1)")
    parser.add_argument("--json", default=None, metavar="OUT.json", help="write every figure as JSON")
    parser.add_argument("--plot", default=None, metavar="PNG",
                        help="draw total error against points per second (labelled files)")
    parser.add_argument("--threads", type=positive_int, default=None, metavar="N",
                        help="run every filter on the same N CPUs (affinity and OMP_NUM_THREADS; "
                             "default: all CPUs, environment as is)")
    parser.add_argument("--compile-cache", default=None, metavar="DIR",
                        help="share JAX's persistent compilation cache in DIR between runs; DIR must be "
                             "private to you (mode 0700; created so), else no cache is shared "
                             "(default: every run compiles from scratch; compile s is then cold)")
    parser.add_argument("--timeout", type=ranged("--timeout"), default=None, metavar="S",
                        help="give up on one (file, filter) run after S seconds (default: no limit)")
    add_model_option(parser)
    add_units_option(parser)
    parser.add_argument("--force", action="store_true", help="overwrite existing --json and --plot files")
    return parser


def run(args: argparse.Namespace) -> int:
    from tqdm.auto import tqdm

    from gfjax.bench import harness
    from gfjax.bench import run as bench
    from gfjax.cli import _job
    from gfjax.cli._common import check_inputs
    from gfjax.errors import InputError
    from gfjax.io import las as las_io

    inputs = las_io.expand_inputs(args.inputs)
    check_inputs(inputs, units=args.units)
    _job.check_outputs([*([("--json", args.json, (".json",))] if args.json else []),
                        *([("--plot", args.plot, (".png",))] if args.plot else [])], inputs=inputs, force=args.force)
    if args.threads is not None:
        try:
            harness.choose_cpus(args.threads)
        except ValueError as err:
            raise InputError(f"--threads: {err}") from None
    if args.compile_cache is not None:            # executables: a private folder or no shared cache
        from gfjax import aot

        folder = aot.private_folder(args.compile_cache, what="shared compilation cache (--compile-cache)")
        args.compile_cache = None if folder is None else str(folder)
    runners, notes = bench.plan(args.methods, args.peers, model=args.model)
    for note in notes:
        print(note, file=sys.stderr)

    pairs = len(inputs) * len(runners)
    records = []
    with tqdm(total=pairs, desc="bench", unit="run", disable=pairs == 1) as bar:
        for record in bench.iter_runs(inputs, runners, repeat=args.repeat, units=args.units,
                                      timeout_s=args.timeout, threads=args.threads,
                                      compile_cache=args.compile_cache):
            records.append(record)
            bar.update(1)
    summary = bench.summarize(records)
    print(bench.format_table(records))
    if len(records) > 1:
        print()
        print(bench.format_summary(summary))
    if args.json:
        document = bench.document(records, repeat=args.repeat, notes=notes, command=bench.command_line(),
                                  threads=args.threads, compile_cache=args.compile_cache is not None)
        with las_io.atomic_output(args.json, force=args.force, input_paths=inputs, suffixes=(".json",),
                                  option="--json", exclusive=not args.force) as tmp:
            tmp.write_text(json.dumps(bench.json_safe(document), indent=2, allow_nan=False) + "\n")
    if args.plot and bench.has_accuracy(records):
        with las_io.atomic_output(args.plot, force=args.force, input_paths=inputs, suffixes=(".png",),
                                  option="--plot", exclusive=not args.force) as tmp:
            bench.plot(records, tmp)
    elif args.plot:
        print(f"--plot {args.plot}: no labelled file ran, nothing drawn", file=sys.stderr)
    return 0 if all(r["status"] == "ok" for r in records) else 1

