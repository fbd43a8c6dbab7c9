"""Methods that do not tile, out of core a piece at a time: labels against the file in memory, and memory.

    nice .venv/bin/python experiments/out_of_core_pieces.py [--methods dmf,masf,csf,vote] [--copies 12]

(a) Labels. `bcts_2` (one contiguous forest tile, 193 x 300 m) is filtered by each method in
memory (as `gfjax filter` runs it: values that follow the data) and out of core on pieces of
500 m (one piece: the same labels), 100 and 50 m, each with the method's survey halo
(`gfjax.survey.lattice.Pieces`, the `gfjax.survey.Runner` that `gfjax filter --out-of-core`
builds); the table gives the share of points labelled as in memory and the seconds of each
run, in this process (programs compiled by an untimed run first).
(b) Memory. `--copies` copies of `bcts_2` side by side in one file (`survey_scale.write_one_file`)
filtered by whole `gfjax filter` processes, in memory and with `--out-of-core` (the pieces the
CLI chooses), run first, under `/usr/bin/time` (its peak resident memory is the child's own,
not that of this process at the fork): peak resident memory and wall time of each.
Writes `experiments/results/out_of_core_pieces.md`.
"""
from __future__ import annotations

import argparse
import functools
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from experiments.survey_scale import GFJAX, SOURCE, write_one_file  # noqa: E402
from gfjax import methods, survey  # noqa: E402
from gfjax.io import las as las_io  # noqa: E402
from gfjax.survey import lattice  # noqa: E402
from gfjax.survey.run import _method_filter  # noqa: E402

RESULTS = ROOT / "experiments" / "results"
SIDES_M = (500.0, 100.0, 50.0)


def in_memory(method, cloud) -> np.ndarray:
    return np.asarray(method.filter(cloud).ground, bool)


def on_pieces(method, path: Path, side_m: float, folder: Path) -> np.ndarray:
    """The file's labels from disk on pieces of `side_m`, as `gfjax filter --out-of-core` runs them."""
    with tempfile.TemporaryDirectory(dir=folder) as own:
        catalog = survey.index([path], own)
        settings = survey.survey_settings(method, catalog, method.Config(), method.Params() if method.Params else None,
                                          fixed=[], whole=False)
        filter_fn = functools.partial(_method_filter, method, settings.config, settings.params, settings.settled,
                                      settings.options)
        halo_m = survey.halo_width(method, settings.config)
        runner = survey.Runner(catalog, filter_fn, None, own, context=False, halo_m=halo_m,
                               pieces=lattice.Pieces(side_m, halo_m))
        return np.array(runner.ground(0))


def process(path: Path, out: Path, method: str, extra: tuple[str, ...]) -> dict:
    """One whole `gfjax filter` process under `/usr/bin/time`: its peak resident memory [GiB] and wall time [s]."""
    argv = ["/usr/bin/time", "-f", "%M %e", *GFJAX, "-q", "filter", str(path), "-o", str(out), "--method", method,
            "--force", *extra]
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed: {done.stderr[-2000:]}")
    peak_kib, wall_s = done.stderr.strip().splitlines()[-1].split()
    return {"wall_s": float(wall_s), "peak_gib": int(peak_kib) / 2**20}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default="dmf,masf,csf,vote")
    parser.add_argument("--copies", type=int, default=12)
    args = parser.parse_args()
    names = args.methods.split(",")
    lines = ["# Out of core a piece at a time: methods that do not tile", "",
             f"Command: `nice .venv/bin/python experiments/out_of_core_pieces.py --methods {args.methods} "
             f"--copies {args.copies}`"]
    with tempfile.TemporaryDirectory(prefix="gfjax-pieces-") as tmp:
        folder = Path(tmp)
        one = write_one_file(folder, args.copies)
        with laspy.open(one) as reader:
            n = reader.header.point_count
        memory_lines = ["", f"## Memory: {args.copies} copies of bcts_2 in one file ({n:,} points), whole processes",
                        "", "| method | in memory: peak GiB / wall s | out of core: peak GiB / wall s |",
                        "| --- | ---: | ---: |"]
        for name in names:
            process(one, folder / "warm.laz", name, ("--out-of-core",))          # compiles, untimed
            memory = process(one, folder / "memory.laz", name, ())
            disk = process(one, folder / "disk.laz", name, ("--out-of-core",))
            memory_lines.append(f"| {name} | {memory['peak_gib']:.2f} / {memory['wall_s']:.1f} | "
                                f"{disk['peak_gib']:.2f} / {disk['wall_s']:.1f} |")
            print(memory_lines[-1], flush=True)
        one.unlink()
        lines += ["", "## Labels: bcts_2 (823,945 points), pieces against the file in memory", "",
                  "| method | in memory s | " + " | ".join(f"{s:.0f} m pieces: same label % / s" for s in SIDES_M) + " |",
                  "| --- | ---: | " + " | ".join("---:" for _ in SIDES_M) + " |"]
        cloud = las_io.read(SOURCE)
        for name in names:
            method = methods.get(name)
            in_memory(method, cloud)                                    # compiles, untimed
            start = time.perf_counter()
            want = in_memory(method, cloud)
            cells = [f"{time.perf_counter() - start:.1f}"]
            for side in SIDES_M:
                on_pieces(method, SOURCE, side, folder)                # compiles the window shapes, untimed
                start = time.perf_counter()
                got = on_pieces(method, SOURCE, side, folder)
                cells.append(f"{100 * np.mean(got == want):.4f} / {time.perf_counter() - start:.1f}")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
        lines += memory_lines
    (RESULTS / "out_of_core_pieces.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
