"""Every method's labels on the 18 shared files, recorded, so a change that should not move a
label (a refactor, a speed-up) is shown not to.

    nice python experiments/labels_check.py --record   # writes results/labels_check.json
    nice python experiments/labels_check.py            # exit 1 naming each (method, file) that moved;
                                                       # results/labels_check.md says what was found

Each method runs with its defaults (`filter(cloud, progress=False)`) on the 11 ISPRS reference
samples, the 3 ISPRS sites, bcts_1/2, Topography and autzen; the record holds, per method and
file, the SHA-256 of the packed ground labels and their count. Each method runs in a child
process of its own (one compilation cache, no state carried between methods).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from experiments.common import DATA, RESULTS  # noqa: E402

RECORD = RESULTS / "labels_check.json"
REPORT = RESULTS / "labels_check.md"
FILES = (*(f"isprs_filtertest/reference/samp{k}-utm.laz" for k in (12, 21, 22, 24, 31, 41, 42, 51, 52, 54, 71)),
         "isprs_filtertest/sites/CSite3_orig-utm.laz", "isprs_filtertest/sites/CSite4_orig-utm.laz",
         "isprs_filtertest/sites/FSite8_orig-utm.laz", "lasR_bcts/bcts_1.laz", "lasR_bcts/bcts_2.laz",
         "lidR_topography/Topography.laz", "pdal_autzen/autzen_trim.laz")


def labels_of(method: str) -> dict[str, dict]:
    """`{file: {"sha256", "ground"}}` of `method`'s defaults on every file of `FILES` present."""
    import numpy as np

    import gfjax
    from gfjax import methods

    found = methods.get(method)
    out = {}
    for relative in FILES:
        path = DATA / relative
        if not path.exists():
            continue
        ground = np.asarray(found.filter(gfjax.read(path), progress=False).ground, bool)
        out[relative] = {"sha256": hashlib.sha256(np.packbits(ground).tobytes()).hexdigest(),
                         "ground": int(ground.sum())}
        print(f"{method:9s} {relative:45s} {out[relative]['ground']:>9,} ground", flush=True)
    return out


def main() -> int:
    from gfjax.methods import names as method_names

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", action="store_true", help="write the record instead of checking against it")
    parser.add_argument("--methods", default=",".join(method_names()))
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(labels_of(args.child)))
        return 0
    got = {}
    for method in args.methods.split(","):
        done = subprocess.run([sys.executable, __file__, "--child", method], check=True, capture_output=True, text=True)
        *lines, last = done.stdout.strip().splitlines()
        print("\n".join(lines), flush=True)
        got[method] = json.loads(last)
    if args.record:
        got["_commit"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                        cwd=HERE).stdout.strip()
        RECORD.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
        print(f"wrote {RECORD}")
        return 0
    record = json.loads(RECORD.read_text())
    moved = [(m, f) for m in got for f in got[m] if record.get(m, {}).get(f) != got[m][f]]
    missing = [(m, f) for m in got for f in record.get(m, {}) if f not in got[m]]
    for m, f in moved:
        print(f"MOVED  {m} {f}: {record.get(m, {}).get(f)} -> {got[m][f]}")
    for m, f in missing:
        print(f"NOT RUN {m} {f}")
    n = sum(len(v) for v in got.values())
    summary = f"{n - len(moved)} of {n} (method, file) labels as recorded" + ("" if moved else ": unchanged")
    print(summary)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=HERE).stdout.strip()
    REPORT.write_text("\n".join([
        "# Labels against the record", "",
        f"`nice python experiments/labels_check.py` at commit {commit or 'unknown'}, against "
        f"`labels_check.json` (recorded at commit {record.get('_commit', 'unknown')}): {summary}.", "",
        *(f"- moved: {m} {f}" for m, f in moved), *(f"- not run: {m} {f}" for m, f in missing)]) + "\n")
    return 1 if moved else 0


if __name__ == "__main__":
    sys.exit(main())
