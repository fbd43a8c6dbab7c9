"""CSF's trend (`gfjax.csf.trend`) against a brute-force loop, and a cloth that follows a slope."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from gfjax.csf.trend import TREND_PERCENTILE, reach_m, trend_at


def brute_force(xyz, use, window_m, cell_m, xy):
    """The same surface built cell by cell, then sampled point by point."""
    lo = xyz[use, :2].min(axis=0)
    ij = np.floor((xyz[use, :2] - lo) / cell_m).astype(int)
    h, w = ij[:, 1].max() + 1, ij[:, 0].max() + 1
    lowest = np.full((h, w), np.inf)
    for (i, j), z in zip(ij, xyz[use, 2]):
        lowest[j, i] = min(lowest[j, i], z)
    filled = lowest.copy()
    cells = np.argwhere(np.isfinite(lowest))
    for r in range(h):
        for c in range(w):
            if not np.isfinite(lowest[r, c]):
                d = ((cells - [r, c]) ** 2).sum(axis=1)
                filled[r, c] = lowest[tuple(cells[np.argmin(d)])]
    k = max(3, 2 * math.ceil(window_m / (2 * cell_m)) + 1)
    half = k // 2

    def square(a, fn):
        out = np.empty_like(a)
        padded = np.pad(a, half, mode="edge")
        for r in range(h):
            for c in range(w):
                out[r, c] = fn(padded[r:r + k, c:c + k])
        return out

    low = square(filled, lambda s: np.sort(s, axis=None)[int(s.size * TREND_PERCENTILE / 100)])
    smooth = square(square(low, np.max), np.mean)
    rows = (xy[:, 1] - lo[1]) / cell_m - 0.5
    cols = (xy[:, 0] - lo[0]) / cell_m - 0.5
    return ndimage.map_coordinates(smooth, [rows, cols], order=1, mode="nearest")


@pytest.mark.parametrize("seed", [0, 1])
def test_trend_matches_brute_force(seed):
    """Points enough for every cell (an empty cell's nearest may tie: the fill has its own test)."""
    rng = np.random.default_rng(seed)
    n = 4000
    xy = rng.uniform(0, 60, (n, 2))
    z = 10 + 0.3 * xy[:, 0] + rng.normal(0, 0.1, n)
    objects = rng.random(n) < 0.2
    z[objects] += rng.uniform(2, 15, objects.sum())
    xyz = np.column_stack([xy, z])
    use = rng.random(n) < 0.9
    probe = rng.uniform(-5, 65, (200, 2))
    for window_m, cell_m in [(30.0, 5.0), (12.0, 3.0)]:
        np.testing.assert_allclose(trend_at(xyz, use, window_m=window_m, cell_m=cell_m)(probe),
                                   brute_force(xyz, use, window_m, cell_m, probe), atol=1e-9)


def test_empty_cells_take_their_nearest_filled_cell():
    xyz = np.array([[0.5, 0.5, 1.0], [9.5, 0.5, 5.0], [0.5, 9.5, 1.0], [9.5, 9.5, 5.0]])
    trend = trend_at(xyz, np.ones(4, bool), window_m=1.0, cell_m=1.0)     # a 3 x 3 window: no smoothing
    west, east = trend(np.array([[1.5, 5.0]])), trend(np.array([[8.5, 5.0]]))
    assert west < east                                      # the west half from the west points


def test_trend_of_a_tilted_plane_with_houses_is_parallel_to_the_plane():
    """What the cloth needs: the slope gone, the houses kept off. The trend stands a constant
    above a uniform slope (its 10th-percentile erosion lowers it less than the dilation raises
    it), which a cloth falling from above does not see."""
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 200, (40_000, 2))
    z = 50 + 0.4 * xy[:, 0] - 0.2 * xy[:, 1] + rng.normal(0, 0.02, len(xy))
    houses = (np.abs((xy[:, 0] % 50) - 25) < 6) & (np.abs((xy[:, 1] % 50) - 25) < 6)
    z[houses] += 8.0                                      # 12 m roofs: narrower than the window
    trend = trend_at(np.column_stack([xy, z]), np.ones(len(xy), bool), window_m=30.0, cell_m=5.0)
    inner = np.all((xy > 30) & (xy < 170), axis=1)
    off = trend(xy[inner]) - (50 + 0.4 * xy[inner, 0] - 0.2 * xy[inner, 1])
    assert np.percentile(off, 97.5) - np.percentile(off, 2.5) < 1.0     # flat after the trend, within 1 m
    assert 0 <= np.median(off) < 3.0


def test_a_cloth_on_the_trend_keeps_a_steep_slope_the_plain_cloth_loses():
    import gfjax
    from gfjax import csf

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 100, (20_000, 2))
    z = 100 + 0.6 * xy[:, 0] + rng.normal(0, 0.02, len(xy))          # 31 degrees
    cloud = gfjax.Cloud.from_xyz(np.column_stack([xy, z]))
    plain = csf.filter(cloud, config=csf.Config())
    followed = csf.filter(cloud)                                        # the values that follow the cloud
    assert followed.settled.chosen == {"trend_m": csf.TREND_M, "rigidness": 1, "class_threshold_m": csf.MAX_THRESHOLD_M,
                                       "time_step": csf.RELIEF_TIME_STEP}
    assert np.mean(plain.ground) < 0.2 < 0.9 < np.mean(followed.ground)
    d = followed.diagnostics                                            # the cloth where the terrain is
    h, w = d.cloth_z.shape
    rows, cols = np.mgrid[0:h, 0:w]
    x = d.origin_m[0] + cols * d.cell_m
    y = d.origin_m[1] + (h - 1 - rows) * d.cell_m
    inside = (x > 5) & (x < 95) & (y > 5) & (y < 95)
    assert np.abs(np.median((d.cloth_z - (100 + 0.6 * x))[inside])) < 0.05


def test_on_relief_the_cloth_reaches_knolls_narrower_than_the_trend():
    """A 0.3 slope under knolls 10 m across and 3 m high: the soft cloth of the trend alone
    bridges their tops (the inverted terrain's hollows); the longer time step and the slope's
    threshold, which relief sets, bring it down on them."""
    import dataclasses

    import gfjax
    from gfjax import csf

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 150, (40_000, 2))
    z = (100 + 0.3 * xy[:, 0] + 1.5 * np.sin(2 * np.pi * xy[:, 0] / 20) * np.sin(2 * np.pi * xy[:, 1] / 20)
         + rng.normal(0, 0.02, len(xy)))
    cloud = gfjax.Cloud.from_xyz(np.column_stack([xy, z]))
    trend_only = csf.filter(cloud, config=dataclasses.replace(csf.Config(), **csf.config.ADAPTED))
    followed = csf.filter(cloud)
    assert followed.settled.chosen["time_step"] == csf.RELIEF_TIME_STEP
    assert np.mean(trend_only.ground) < 0.95 < 0.995 < np.mean(followed.ground)


def test_under_a_sparse_canopy_the_trend_widens_to_stay_on_the_ground():
    """0.06 points/m², 7.5 % of them ground under 5-25 m of canopy (the density of IGN's thinned
    forest tiles): a 30 m trend's 5 m cells hold one or two points, mostly treetops, and the trend
    rides the canopy; the window `adapt` sets for so sparse a cloud holds four a cell."""
    from gfjax import adaptive, csf
    from gfjax.csf.trend import trend_at

    rng = np.random.default_rng(0)
    side = 600.0
    xy = rng.uniform(0, side, (int(0.06 * side**2), 2))
    ground_z = 100 + 0.05 * xy[:, 0]
    is_ground = rng.random(len(xy)) < 0.075
    xyz = np.column_stack([xy, ground_z + np.where(is_ground, 0.0, rng.uniform(5, 25, len(xy)))])
    window = csf.adapt(adaptive.measure(xyz))["trend_m"]
    assert window > 45
    inner = np.all((xy > 60) & (xy < side - 60), axis=1)

    def above_ground(window_m: float) -> float:
        trend = trend_at(xyz, np.ones(len(xyz), bool), window_m=window_m, cell_m=window_m / csf.config.TREND_CELLS)
        return float(np.median(trend(xy[inner]) - ground_z[inner]))

    assert above_ground(csf.TREND_M) > 4.0
    assert above_ground(window) < 1.5


def test_a_framed_cloud_on_its_trend_falls_as_the_cloud_alone():
    """A survey's window (a frame) lays the cloth on the survey's lattice; with a trend taken
    off, the cloth still falls from the window's own highest point: a window holding the
    whole cloud labels it as the cloud alone."""
    from gfjax import csf
    from gfjax.io.cloud import Cloud, Frame, Points

    rng = np.random.default_rng(5)
    xy = rng.uniform(0.0, 120.0, (12_000, 2))
    z = 0.3 * xy[:, 0] + 4.0 * np.sin(xy[:, 1] / 15.0) + rng.normal(0.0, 0.05, len(xy))
    house = np.all(np.abs(xy - 60.0) < 8.0, axis=1)
    z[house] += 6.0
    xyz = np.column_stack([xy + [400_000.0, 5_000_000.0], z + 200.0])
    cloud = Cloud.from_xyz(xyz)
    config = csf.Config(trend_m=30.0)
    alone = np.asarray(csf.filter(cloud, config=config).ground)
    frame = Frame(xyz.min(axis=0), xyz[:, :2].max(axis=0))
    window = Points(xyz_m=xyz, classification=cloud.classification, return_number=cloud.return_number,
                    number_of_returns=cloud.number_of_returns, ignored=cloud.ignored, name="window", frame=frame)
    np.testing.assert_array_equal(np.asarray(csf.filter(window, config=config).ground), alone)
    assert alone[~house].mean() > 0.95 and not alone[house].any()


def test_a_window_laid_on_the_whole_lattice_has_the_whole_trend_inside():
    """A window's trend with its first cell on the whole cloud's lattice (`corner_m`) is the
    whole cloud's trend wherever the window holds all it reads (`reach_m` around it); laid from
    the window's own corner, its cells and so its surface differ."""
    rng = np.random.default_rng(4)
    n = 30_000
    xy = rng.uniform(0, 300, (n, 2))
    z = 50 + 0.2 * xy[:, 0] + 3 * np.sin(xy[:, 1] / 25) + rng.normal(0, 0.1, n)
    objects = rng.random(n) < 0.2
    z[objects] += rng.uniform(2, 15, objects.sum())
    xyz = np.column_stack([xy, z])
    use = np.ones(n, bool)
    window_m, cell_m = 30.0, 5.0
    whole = trend_at(xyz, use, window_m=window_m, cell_m=cell_m)
    inside = np.all((xy > 83) & (xy < 217), axis=1)
    lo = xy.min(axis=0)

    def laid(margin_m: float, corner: bool = True) -> np.ndarray:
        part = np.all((xy > 83 - margin_m) & (xy < 217 + margin_m), axis=1)
        first = lo + np.floor((xy[part].min(axis=0) - lo) / cell_m) * cell_m if corner else None
        return trend_at(xyz[part], use[part], window_m=window_m, cell_m=cell_m, corner_m=first)(xy[inside])

    reach = reach_m(window_m, cell_m)
    np.testing.assert_allclose(laid(reach), whole(xy[inside]), atol=1e-9)
    assert np.abs(laid(reach, corner=False) - whole(xy[inside])).max() > 0.05
