"""Peak resident memory of each window of a tiled method's survey.

    .venv/bin/python experiments/survey_window_peaks.py [--files 42] [--method smrf] [--release]

Writes `--files` copies of bcts_2 (`survey_scale.write_survey`), then filters them as one
survey the way the `gfjax` program does (`gfjax.cli.main`, heap settings included). Before each
tile of the survey's lattice the process's high-water mark is reset (`/proc/self/clear_refs`),
after it one line gives that tile's peak (`VmHWM`) and what the process still holds (`VmRSS`,
anonymous and file-backed), in MiB. `--release` drops the compiled programs after every tile
(read back from the program store for the next), to see whether they are what grows. Run it
twice: the first run of new code compiles, and compiling raises the first windows' peaks.
Linux only. The survey's largest per-tile peak against the 4-file one is the ratio of
`experiments/results/survey_scale.md`.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from survey_scale import write_survey  # noqa: E402


def status_mib() -> dict[str, int]:
    """`VmHWM`, `VmRSS`, `RssAnon` and `RssFile` of this process [MiB]."""
    found = {}
    for line in open("/proc/self/status"):
        key, _, value = line.partition(":")
        if key in ("VmHWM", "VmRSS", "RssAnon", "RssFile"):
            found[key] = int(value.split()[0]) // 1024
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=42, help="copies of bcts_2 in the survey")
    parser.add_argument("--method", default="smrf", help="a tiled method (smrf, pmf)")
    parser.add_argument("--release", action="store_true", help="drop the compiled programs after each tile")
    args = parser.parse_args()

    from gfjax import heap

    heap.tune()                                    # as the `gfjax` program sets it, before JAX's threads
    from gfjax import aot
    from gfjax.cli.main import main as gfjax_main
    from gfjax.survey import lattice

    run_tile = lattice.TileLabels._run

    def measured(self, key):
        with open("/proc/self/clear_refs", "w") as reset:
            reset.write("5")                       # the high-water mark starts again here
        start = time.perf_counter()
        run_tile(self, key)
        if args.release:
            aot.release()
        mib = status_mib()
        print(f"tile {key}: {time.perf_counter() - start:.1f} s, peak {mib['VmHWM']} MiB, then "
              f"{mib['VmRSS']} MiB ({mib['RssAnon']} anonymous, {mib['RssFile']} file)", flush=True)

    lattice.TileLabels._run = measured
    with tempfile.TemporaryDirectory(prefix="gfjax-window-peaks-") as tmp:
        folder, out = Path(tmp) / "in", Path(tmp) / "out"
        folder.mkdir()
        out.mkdir()
        paths = write_survey(folder, args.files)
        print("before the first tile:", status_mib(), flush=True)
        gfjax_main(["-q", "filter", *map(str, paths), "-o", str(out), "--method", args.method])


if __name__ == "__main__":
    main()
