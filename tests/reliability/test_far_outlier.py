"""A stray point kilometres from the others must not cost memory for the empty box between
them: every method filters each group of points far apart as a cloud of its own (the tiled
ones, SMRF and PMF, `gfjax.tiling.driver.classify_groups`; the whole-cloud ones, CSF, DMF and
MASF, `gfjax.tiling.driver.filter_groups`), and on a survey's frame, where the lattice may not move,
the tiles skip empty ground and the whole-cloud diagnostic rasters only touch the pages of
the tiles' cores."""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gfjax import csf, dmf, masf, pmf, smrf
from gfjax.io.cloud import Cloud, Frame
from gfjax.tiling import groups

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)

REPO = Path(__file__).resolve().parents[2]

_PROGRAM = r"""
import resource, sys
import dataclasses, importlib
import numpy as np, gfjax
method = importlib.import_module("gfjax." + sys.argv[2])
rng = np.random.default_rng(0)
xy = rng.uniform(0, 140, (20000, 2))
if sys.argv[1] == "outlier":
    xy = np.vstack([xy, [[10_000.0, 10_000.0]]])
cloud = gfjax.Cloud.from_xyz(np.column_stack([xy + [5e5, 5e6], 100 + rng.normal(0, 0.1, len(xy))]))
if sys.argv[3] == "frame":                    # a survey's frame: SMRF's lattice may not move
    from gfjax.io.cloud import Frame
    cloud = dataclasses.replace(cloud, frame=Frame.of(cloud.xyz_m))
result = method.filter(cloud)
rows = result.diagnostics.zimin.shape[0] if sys.argv[3] == "frame" else 0
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, rows, int(result.ground.sum()))
"""


def _peak(kind: str, method: str, frame: str) -> tuple[int, int, int]:
    done = subprocess.run([sys.executable, "-c", _PROGRAM, kind, method, frame], capture_output=True, text=True, cwd=REPO,
                          timeout=600, env={"GFJAX_CACHE": "0", "PATH": "/usr/bin:/bin",
                                            "XLA_FLAGS": os.environ.get("XLA_FLAGS", "")})
    assert done.returncode == 0, done.stderr
    return tuple(map(int, done.stdout.split()))


@pytest.mark.parametrize("method, frame", [("smrf", "frame"), ("csf", "own")])
def test_a_point_10_km_away_adds_no_memory_for_the_empty_box(method, frame):
    alone_kib, _, alone_ground = _peak("none", method, frame)
    far_kib, rows, ground = _peak("outlier", method, frame)
    if frame == "frame":
        assert rows >= 10_000                        # the rasters do span the 10 km box ...
    assert far_kib - alone_kib < 500 * 1024          # ... but one at float64 would be 0.8 GB, six 4.8 GB
    assert ground >= alone_ground > 19_000           # (CSF's cloth over the box asked for 1.2 TB)


@pytest.mark.parametrize("method", [csf, dmf, masf, smrf, pmf], ids=["csf", "dmf", "masf", "smrf", "pmf"])
def test_far_points_leave_the_labels_of_the_others_as_they_are_alone(method):
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 90, (8000, 2))
    z = 100 + 0.05 * xy[:, 0] + rng.normal(0, 0.1, len(xy))
    z[:1200] += rng.uniform(2, 15, 1200)                                  # low objects and trees
    main = np.column_stack([xy + [5e5, 5e6], z])
    strays = np.array([[5e5 + 10_000, 5e6 + 10_000, 104.0], [5e5 - 3_000, 5e6 + 50, 101.0]])
    assert groups.members(np.vstack([main, strays])[:, :2], groups.GAP_M) is not None
    fixed = {"config": method.Config()}          # as given: no value follows the cloud, which the strays change
    alone = method.filter(Cloud.from_xyz(main), **fixed)
    with_strays = method.filter(Cloud.from_xyz(np.vstack([main, strays])), **fixed)
    assert with_strays.diagnostics is None                                # filtered group by group
    assert alone.diagnostics is not None
    assert 0.5 < np.mean(alone.ground) < 0.95
    np.testing.assert_array_equal(with_strays.ground[:len(main)], alone.ground)
    for k, stray in enumerate(strays):                                    # a point alone is ground
        assert method.filter(Cloud.from_xyz(stray[None]), **fixed).ground[0] == with_strays.ground[len(main) + k]


@pytest.mark.parametrize("method, n, side_m", [(pmf, 2_000, 50_000.0), (smrf, 600, 10_000.0),
                                               (dmf, 1_000, 30_000.0), (masf, 8_000, 100_000.0),
                                               (csf, 140, 6_000.0)], ids=["pmf", "smrf", "dmf", "masf", "csf"])
def test_points_spread_over_a_large_box_cost_their_tiles_not_the_box(method, n, side_m):
    """Up to 8,000 points over up to 100 x 100 km (PMF: 2,000 over 50 x 50 km, 10,000 tiles of
    500 m, 2.5 x 10^9 cells of 1 m; MASF: 8,000 over 100 x 100 km): each group
    of points far from the others is filtered as a cloud of its own (SMRF and PMF in small
    windows batched together); a group's labels are those it gets alone. The box sets the
    memory at stake, not the points: each method still meets ten or more groups of two points
    or more (CSF ten, MASF 288), every group a run of its own."""
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, side_m, (n, 2))
    xy[:40] = xy[0] + rng.uniform(0, 30, (40, 2))                       # one group of 40 points
    z = 100 + rng.normal(0, 1.0, n)
    z[1] += 6.0                                                           # a roof in it
    cloud = Cloud.from_xyz(np.column_stack([xy + [5e5, 5e6], z]))
    fixed = {"config": method.Config()}          # as given: the group alone would settle other values
    result = method.filter(cloud, **fixed)
    assert result.diagnostics is None and result.ground.shape == (n,)
    assert np.mean(result.ground[40:]) > 0.8 and not result.ground[1]          # most lone: ground
    group = method.filter(Cloud.from_xyz(cloud.xyz_m[:40]), **fixed)
    np.testing.assert_array_equal(result.ground[:40], group.ground)


@pytest.mark.parametrize("method", [smrf, pmf])
def test_cells_of_no_core_are_zero_and_cores_keep_their_heights(method):
    rng = np.random.default_rng(3)
    xy = np.vstack([rng.uniform(0, 60, (3000, 2)), rng.uniform(0, 60, (3000, 2)) + 1500.0])
    z = 200 + 0.01 * xy[:, 0]
    cloud = Cloud.from_xyz(np.column_stack([xy + [5e5, 5e6], z]))
    on_frame = dataclasses.replace(cloud, frame=Frame.of(cloud.xyz_m))  # a survey's: the lattice stays
    zimin = method.filter(on_frame).diagnostics.zimin
    assert zimin.shape[0] > 1500 and zimin.shape[1] > 1500
    middle = zimin[zimin.shape[0] // 2 - 100:zimin.shape[0] // 2 + 100, 700:800]
    assert np.all(middle == 0)                        # between the two groups: no tile, no data
    sw = zimin[-50:, :50]                             # the south-west group: absolute heights
    assert np.all((sw > 199) & (sw < 202))


def test_points_hundreds_of_metres_apart_take_a_voxel_wider_than_a_tile():
    """DMF's W (Eq. 1, from the mean nearest-neighbour distance) of two points 281 m apart (one
    group: their 100 m cells touch) is over 500 m, wider than a tile: each tile core is then
    one voxel."""
    xyz = np.array([[5e5, 5e6, 100.0], [5e5 + 199.0, 5e6 + 199.0, 101.0]])
    result = dmf.filter(Cloud.from_xyz(xyz))
    assert result.diagnostics.cell_m > 500.0
    assert result.ground.all()
