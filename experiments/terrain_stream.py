"""Peak memory and CPU time of a survey's terrain statistics (`gfjax.survey.survey_terrain`) alone.

    PYTHONPATH=<code> nice .venv/bin/python experiments/terrain_stream.py FILE_OR_FOLDER

Indexes the file (or every `.laz` of the folder) as a survey, then measures its terrain, and
prints the CPU and wall time of that step, the process's peak resident memory before and after
it, and the `Terrain`. Run it once per version of the code (`PYTHONPATH`) to compare them; the
inputs are `experiments/survey_scale.py`'s copies of bcts_2 (`write_one_file`, `write_survey`).
"""
from __future__ import annotations

import resource
import sys
import tempfile
import time
from pathlib import Path

from gfjax import survey
from gfjax.survey import halo


def main() -> None:
    source = Path(sys.argv[1])
    paths = sorted(source.glob("*.laz")) if source.is_dir() else [source]
    with tempfile.TemporaryDirectory() as tmp:
        catalog = survey.index(paths, tmp)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        cpu_s, wall_s = time.process_time(), time.perf_counter()
        terrain = halo.survey_terrain(catalog)
        cpu_s, wall_s = time.process_time() - cpu_s, time.perf_counter() - wall_s
        after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(f"cpu_s {cpu_s:.2f} wall_s {wall_s:.2f} peak_before_MiB {before / 1024:.0f} peak_after_MiB {after / 1024:.0f}")
    print(repr(terrain))


if __name__ == "__main__":
    main()
