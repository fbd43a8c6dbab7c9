"""`gfjax eval IN...`: point accuracy of ground labels, as a table or JSON.

Two ways to get the labels that are scored:

- `--reference REF...` (one per input): the inputs are classified files (ground = class 2)
  and each is compared with its reference file (ground = `--reference-class`). Both must
  hold the same points: in the same order, or else matched on exact scaled integer XYZ (the
  table says so). With `--method`, the method's result is scored instead of the input's class.
- `--method NAME` alone: the method runs on labelled inputs and is scored against their own
  labels (ground = `--reference-class`), e.g. the ISPRS reference samples.

Noise (7, 18), water (9), overlap (12) and withheld points of the reference are not scored
(`gfjax.metrics.UNSCORED_CLASSES`; a vendor keeps water and overlap apart from ground by rules
of its own), unless one of them is `--reference-class`; nor, with `--returns last`, non-last
returns. With several inputs the last row is the unweighted mean over files.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from gfjax.cli import _job
from gfjax.cli._common import add_method_options, add_units_option, check_inputs, method_setup, ranged
from gfjax.errors import InputError
from gfjax.io import las as las_io
from gfjax.io.cloud import Cloud

COLUMNS = [("n_points", "points", "{:,}"), ("oa", "OA %", "{:.2%}"), ("total_error", "total err %", "{:.2%}"),
           ("type1", "type I %", "{:.2%}"), ("type2", "type II %", "{:.2%}"), ("kappa", "kappa", "{:.4f}"),
           ("f1", "F1", "{:.4f}"), ("iou_ground", "IoU ground", "{:.4f}"),
           ("iou_nonground", "IoU non-ground", "{:.4f}")]


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("eval", help="score ground labels against reference labels",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="IN", help="LAS/LAZ files, folders or globs")
    parser.add_argument("--reference", nargs="+", default=None, metavar="REF",
                        help="reference files, one per input, in the same order")
    add_method_options(parser, method_help="run this filter on the inputs and score its result")
    parser.add_argument("--reference-class", type=ranged("--reference-class"), default=2, metavar="CODE",
                        help="class code of ground in the reference (default 2)")
    parser.add_argument("--returns", choices=("all", "last"), default="all",
                        help="returns the method uses and that are scored (default all)")
    parser.add_argument("--json", default=None, metavar="OUT.json", help="also write the metrics as JSON")
    add_units_option(parser)
    parser.add_argument("--force", action="store_true", help="overwrite an existing --json file")
    return parser


def match_points(cloud: Cloud, reference: Cloud) -> tuple[np.ndarray | None, str]:
    """Index of each point of `cloud` in `reference`, or None when the order is the same.

    Points are compared as integers on the reference's scale/offset grid, exactly. Returns
    `(index int64 (n,) or None, note)`.

    Raises:
      InputError: different point counts, or different sets of XYZ positions.
    """
    n, m = cloud.n_points, reference.n_points
    if n != m:
        raise InputError(f"{reference.name}: {m:,} points, but {cloud.name} has {n:,}: not the same points")
    scales, offsets = reference.las.header.scales, reference.las.header.offsets
    key_in = np.round((cloud.xyz - offsets) / scales).astype(np.int64)
    key_ref = np.round((reference.xyz - offsets) / scales).astype(np.int64)
    if np.array_equal(key_in, key_ref):
        return None, "same point order"
    order_in = np.lexsort(key_in.T[::-1])
    order_ref = np.lexsort(key_ref.T[::-1])
    if not np.array_equal(key_in[order_in], key_ref[order_ref]):
        differ = int(np.count_nonzero(np.any(key_in[order_in] != key_ref[order_ref], axis=1)))
        raise InputError(f"{reference.name}: not the same XYZ positions as {cloud.name} "
                         f"({differ:,} of {n:,} differ after sorting)")
    index = np.empty(n, dtype=np.int64)
    index[order_in] = order_ref
    sorted_keys = key_ref[order_ref]
    repeats = int(np.count_nonzero(np.all(sorted_keys[1:] == sorted_keys[:-1], axis=1)))
    note = "point order differs: matched on exact scaled integer XYZ"
    if repeats:
        note += f" ({repeats:,} repeated positions matched in file order)"
    return index, note


def _labels(args: argparse.Namespace, setup, source: Path, reference: Path | None) -> dict:
    from gfjax import metrics

    cloud = las_io.read(source, units=args.units)
    if setup is not None:
        result = setup.filter(cloud, returns=args.returns, progress=False)
        pred = np.asarray(result.ground, dtype=bool)
        scored = cloud.filter_mask(args.returns)
    else:
        pred = cloud.classification == 2
        scored = ~cloud.ignored
    if reference is None:
        ref_class, note = cloud.classification, "own labels"
    else:
        ref_cloud = las_io.read(reference, units=args.units)
        index, note = match_points(cloud, ref_cloud)
        ref_class, ref_ignored = ref_cloud.classification, ref_cloud.ignored
        if index is not None:
            ref_class, ref_ignored = ref_class[index], ref_ignored[index]
        scored = scored & ~ref_ignored
    ref = ref_class == np.uint8(args.reference_class)
    scored = scored & (metrics.scored_mask(ref_class) | ref)
    return {"pred": pred, "ref": ref, "scored": scored, "match": note}


def format_table(rows: list[tuple[str, dict]]) -> str:
    """Rows of (label, metrics) as an aligned text table."""
    header = ["file", *(title for _, title, _ in COLUMNS)]
    body = [[label, *(fmt.format(metrics[key] if key != "n_points" else int(round(metrics[key])))
                      for key, _, fmt in COLUMNS)] for label, metrics in rows]
    widths = [max(len(r[i]) for r in [header, *body]) for i in range(len(header))]
    lines = ["  ".join(cell.ljust(widths[0]) if i == 0 else cell.rjust(widths[i]) for i, cell in enumerate(r))
             for r in [header, *body]]
    lines.insert(1, "-" * len(lines[0]))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from tqdm.auto import tqdm

    from gfjax import metrics

    inputs = las_io.expand_inputs(args.inputs)
    references: list[Path | None] = [None] * len(inputs)
    if args.reference:
        # expanded one by one: a reference may serve several inputs
        references = [path for pattern in args.reference for path in las_io.expand_inputs([pattern])]
        if len(references) != len(inputs):
            raise InputError(f"--reference: {len(references)} reference files for {len(inputs)} inputs; "
                             "give one per input, in the same order")
    elif not (args.method or args.params):
        raise InputError("--reference or --method: give reference files, or a method to run on labelled files")
    # Units matter only to a method; matching a reference compares the stored integers.
    check_inputs([*inputs, *(r for r in references if r is not None)], units=args.units,
                 metres_matter=bool(args.method or args.params))
    if args.json:
        _job.check_outputs([("--json", args.json, (".json",))], inputs=[*inputs, *(r for r in references if r)],
                           force=args.force)
    setup = method_setup(args) if (args.method or args.params) else None

    rows, records = [], []
    for source, reference in tqdm(list(zip(inputs, references)), desc="files", unit="file",
                                  disable=len(inputs) == 1):
        start = time.perf_counter()
        labels = _labels(args, setup, source, reference)
        scores = metrics.point_metrics(labels["pred"], labels["ref"], mask=labels["scored"])
        rows.append((source.name, scores))
        records.append({"input": str(source), "reference": str(reference) if reference else None,
                        "match": labels["match"], "seconds": time.perf_counter() - start, "metrics": scores})
    mean = metrics.mean_over_samples([m for _, m in rows]) if len(rows) > 1 else None
    what = f"method {setup.name}" if setup else "class 2 of the inputs"
    print(f"scored {what} against {'reference files' if args.reference else 'their own labels'} "
          f"(ground = class {args.reference_class})")
    for record in records:
        if record["match"] not in ("same point order", "own labels"):
            print(f"  {record['input']}: {record['match']}")
    print(format_table(rows + ([("mean (unweighted)", mean)] if mean else [])))
    if args.json:
        document = {"method": setup.name if setup else None, "reference_class": args.reference_class,
                    "returns": args.returns, "files": records, "mean": mean}
        with las_io.atomic_output(args.json, force=args.force, input_paths=inputs, suffixes=(".json",),
                                  option="--json", exclusive=not args.force) as tmp:
            tmp.write_text(json.dumps(document, indent=2) + "\n")
    return 0
