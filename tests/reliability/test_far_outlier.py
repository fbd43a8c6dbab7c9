"""A stray point kilometres from the others must not cost memory for the empty box between
them: the tiles skip empty ground, and the whole-cloud diagnostic rasters only touch the
pages of the tiles' cores."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gfjax import pmf, smrf
from gfjax.io.cloud import Cloud

REPO = Path(__file__).resolve().parents[2]

_PROGRAM = r"""
import resource, sys
import numpy as np, gfjax
from gfjax import smrf
rng = np.random.default_rng(0)
xy = rng.uniform(0, 140, (20000, 2))
if sys.argv[1] == "outlier":
    xy = np.vstack([xy, [[10_000.0, 10_000.0]]])
cloud = gfjax.Cloud.from_xyz(np.column_stack([xy + [5e5, 5e6], 100 + rng.normal(0, 0.1, len(xy))]))
result = smrf.filter(cloud)
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, result.diagnostics.zimin.shape[0], int(result.ground.sum()))
"""


def _peak(kind: str) -> tuple[int, int, int]:
    done = subprocess.run([sys.executable, "-c", _PROGRAM, kind], capture_output=True, text=True, cwd=REPO,
                          timeout=600, env={"GFJAX_CACHE": "0", "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    return tuple(map(int, done.stdout.split()))


def test_a_point_10_km_away_adds_no_memory_for_the_empty_box():
    alone_kib, _, alone_ground = _peak("none")
    far_kib, rows, ground = _peak("outlier")
    assert rows >= 10_000                            # the rasters do span the 10 km box ...
    assert far_kib - alone_kib < 300 * 1024          # ... but six of them at float64 would be 4.8 GB
    assert ground >= alone_ground > 19_000


@pytest.mark.parametrize("method", [smrf, pmf])
def test_cells_of_no_core_are_zero_and_cores_keep_their_heights(method):
    rng = np.random.default_rng(3)
    xy = np.vstack([rng.uniform(0, 60, (3000, 2)), rng.uniform(0, 60, (3000, 2)) + 1500.0])
    z = 200 + 0.01 * xy[:, 0]
    result = method.filter(Cloud.from_xyz(np.column_stack([xy + [5e5, 5e6], z])))
    zimin = result.diagnostics.zimin
    assert zimin.shape[0] > 1500 and zimin.shape[1] > 1500
    middle = zimin[zimin.shape[0] // 2 - 100:zimin.shape[0] // 2 + 100, 700:800]
    assert np.all(middle == 0)                        # between the two groups: no tile, no data
    sw = zimin[-50:, :50]                             # the south-west group: absolute heights
    assert np.all((sw > 199) & (sw < 202))
