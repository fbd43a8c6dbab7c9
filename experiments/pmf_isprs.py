"""gfjax PMF with its defaults on the 11 ISPRS samples: total error, type I/II, kappa.

Usage:
  nice .venv/bin/python experiments/pmf_isprs.py [FILES...] [--json OUT]
Defaults: cell 1 m, max window 33 m (windows 3, 5, 9, 17, 33 cells), slope 1, initial
distance 0.15 m, max distance 2.5 m. Scored on `cloud.filter_mask()` points against ASPRS
class 2. Results: `experiments/results/pmf_isprs.json`.
"""
from __future__ import annotations

import json
import platform
import sys
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gfjax  # noqa: E402
from experiments.common import files_parser, first_and_again, isprs_samples, score, write_json  # noqa: E402
from gfjax import pmf  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = files_parser(__doc__, isprs_samples(), "pmf_isprs.json")
    args = parser.parse_args(argv)
    rows = []
    for path in args.files:
        cloud = gfjax.read(path)
        use = cloud.filter_mask()
        _, seconds, _, result = first_and_again(lambda: pmf.filter(cloud))      # warm-up (compile), then timed
        m = score(result.ground, cloud, use)
        row = {"file": path.name, "n_points": int(use.sum()), "total_error": m["total_error"],
               "type1": m["type1"], "type2": m["type2"], "kappa": m["kappa"], "time_s": seconds}
        rows.append(row)
        print(f"{row['file']:16s} n={row['n_points']:6d} TE={m['total_error']:.4f} T1={m['type1']:.4f} "
              f"T2={m['type2']:.4f} kappa={m['kappa']:.4f} t={seconds:.3f}s", flush=True)
    summary = {key: float(np.mean([r[key] for r in rows])) for key in ("total_error", "type1", "type2", "kappa")}
    summary["min_kappa"] = float(np.min([r["kappa"] for r in rows]))
    env = {"command": "nice .venv/bin/python " + " ".join(["experiments/pmf_isprs.py", *(argv or sys.argv[1:])]),
           "jax": jax.__version__, "device": str(jax.devices()[0]), "platform": platform.platform(),
           "config": str(pmf.Config()), "windows_px": list(pmf.Config().windows_px),
           "params": {k: float(v) for k, v in vars(pmf.Params()).items()}}
    print("mean over samples:", json.dumps(summary))
    write_json(args.json, env, summary, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
