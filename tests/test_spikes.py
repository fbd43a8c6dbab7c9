"""The spike guard against a brute-force loop, and on clouds whose spikes are known."""
from __future__ import annotations

import numpy as np
import pytest

from gfjax import spikes
from gfjax.io import columns


def brute_force(xyz, ground, *, threshold_m, slope, k):
    """Each ground point against its k nearest ground neighbours, one at a time."""
    out = ground.copy()
    index = np.flatnonzero(ground)
    for i in index:
        others = index[index != i]
        d = np.hypot(*(xyz[others, :2] - xyz[i, :2]).T)
        near = np.argsort(d, kind="stable")[:k]
        allowed = threshold_m + slope * np.median(d[near])
        if abs(xyz[i, 2] - np.median(xyz[others[near], 2])) > allowed:
            out[i] = False
    return out


def terrain(n=400, seed=0, slope=0.0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 100, (n, 2))
    z = 50 + slope * xy[:, 0] + rng.normal(0, 0.05, n)
    return np.column_stack([xy, z])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_brute_force_on_random_labels(seed):
    rng = np.random.default_rng(seed)
    xyz = terrain(seed=seed)
    xyz[rng.choice(400, 30, replace=False), 2] += rng.uniform(-8, 8, 30)
    ground = rng.random(400) < 0.8
    for threshold_m, slope, k in [(1.0, 0.5, 8), (0.3, 0.0, 4), (2.0, 1.0, 12)]:
        np.testing.assert_array_equal(spikes.despike(xyz, ground, threshold_m=threshold_m, slope=slope, k=k),
                                      brute_force(xyz, ground, threshold_m=threshold_m, slope=slope, k=k))


def test_neighbours_found_a_slice_at_a_time_give_the_same_labels(monkeypatch):
    rng = np.random.default_rng(5)
    xyz = terrain(seed=5)
    xyz[rng.choice(400, 30, replace=False), 2] += rng.uniform(-8, 8, 30)
    ground = rng.random(400) < 0.8
    monkeypatch.setattr(spikes, "QUERY_ROWS", 37)                 # nine slices, the last a short one
    np.testing.assert_array_equal(spikes.despike(xyz, ground),
                                  brute_force(xyz, ground, threshold_m=spikes.THRESHOLD_M, slope=spikes.SLOPE,
                                              k=spikes.NEIGHBOURS))


@pytest.mark.parametrize("seed", [0, 1])
def test_stacks_of_coincident_points_match_brute_force(seed):
    """Places held by more than k points: each of their points is compared with its stack
    (its k nearest are at distance 0 among them, which of them a tie); the points around see
    k + 1 of them, and points far from them get the brute force's labels."""
    rng = np.random.default_rng(seed)
    xyz = terrain(n=300, seed=seed)
    stack = np.repeat(xyz[:3], [12, 30, 9], axis=0)                    # three places, 12, 30 and 9 deep
    stack[:, 2] = stack[:, 2] + rng.normal(0, 0.05, len(stack))
    stack[5, 2] += 4.0                                                  # one high point in the first stack
    xyz = np.vstack([xyz, stack])
    ground = np.ones(len(xyz), bool)
    got = spikes.despike(xyz, ground, k=8)
    high = 300 + 5
    assert not got[high] and got[300:high].all() and got[high + 1:].all()     # the stacks' ground stays
    outside = np.arange(3, 300)                                         # away from the stacks: as before
    to_stacks = np.hypot(*(xyz[outside, None, :2] - xyz[None, :3, :2]).transpose(2, 0, 1)).min(axis=1)
    far = to_stacks > 30
    want = brute_force(xyz, ground, threshold_m=spikes.THRESHOLD_M, slope=spikes.SLOPE, k=8)
    np.testing.assert_array_equal(got[outside[far]], want[outside[far]])


@pytest.mark.parametrize("seed", [0, 1])
def test_points_no_median_can_unmake_are_not_queried_and_labels_match_brute_force(seed):
    """A dense, gentle cloud: most ground points lie within `THRESHOLD_M` of every height of the
    5 x 5 cells around them and go unqueried; the spikes, points a hair off their neighbours'
    tolerance and a sparse corner where cells hold k points or fewer are queried, all as the
    brute force labels them."""
    rng = np.random.default_rng(seed)
    xyz = terrain(n=2500, seed=seed, slope=0.01)
    xyz[:, :2] *= 0.5                                              # 50 x 50 m: 1 m spacing
    corner = np.column_stack([rng.uniform(60, 90, (40, 2)), 50 + rng.normal(0, 0.05, 40)])
    xyz = np.vstack([xyz, corner])
    spiked = rng.choice(2500, 3, replace=False)
    xyz[spiked, 2] += [-1.2, 0.95, 1.05]                                 # on both sides of 1 m
    ground = rng.random(len(xyz)) < 0.9
    index = np.flatnonzero(ground)
    xy = xyz[index, :2] - xyz[index, :2].min(axis=0)
    unsure = spikes._unsure(xy, xyz[index, 2], threshold_m=spikes.THRESHOLD_M, slope=spikes.SLOPE,
                            k=spikes.NEIGHBOURS)
    assert unsure.size < 0.75 * index.size
    in_corner = np.flatnonzero(index >= 2500)
    assert np.isin(in_corner, unsure).all()                       # too few a cell there
    np.testing.assert_array_equal(spikes.despike(xyz, ground),
                                  brute_force(xyz, ground, threshold_m=spikes.THRESHOLD_M, slope=spikes.SLOPE,
                                              k=spikes.NEIGHBOURS))


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (3, 7), (40, 30)])
def test_the_5_by_5_extremes_match_scipy(shape):
    from scipy import ndimage

    rng = np.random.default_rng(sum(shape))
    grid = rng.normal(size=shape)
    grid[rng.random(shape) < 0.3] = np.inf                          # empty cells
    np.testing.assert_array_equal(spikes._around(grid, np.inf, np.min),
                                  ndimage.minimum_filter(grid, size=5, mode="constant", cval=np.inf).reshape(-1))
    np.testing.assert_array_equal(spikes._around(-grid, -np.inf, np.max),
                                  ndimage.maximum_filter(-grid, size=5, mode="constant", cval=-np.inf).reshape(-1))


def test_every_point_is_queried_where_the_cells_prove_nothing():
    """A negative slope (a tolerance below `threshold_m`), no threshold, points on one line (no
    area) and a strip whose cells would outnumber its points: every point is compared with its
    neighbours."""
    xyz = terrain(n=400)
    xy, z = xyz[:, :2] - xyz[:, :2].min(axis=0), xyz[:, 2]
    for kwargs in (dict(threshold_m=1.0, slope=-0.1), dict(threshold_m=-1.0, slope=0.5),
                   dict(threshold_m=np.nan, slope=0.5)):
        np.testing.assert_array_equal(spikes._unsure(xy, z, k=8, **kwargs), np.arange(400))
    line = np.column_stack([xy[:, 0], np.zeros(400)])
    np.testing.assert_array_equal(spikes._unsure(line, z, threshold_m=1.0, slope=0.5, k=8), np.arange(400))
    strip = np.column_stack([xy[:, 0] * 10, xy[:, 1] * 1e-5])        # 1 km by 1 mm: cells the points do not fill
    np.testing.assert_array_equal(spikes._unsure(strip, z, threshold_m=1.0, slope=0.5, k=8), np.arange(400))


def test_a_million_coincident_points_cost_what_a_few_do():
    xyz = np.vstack([np.tile([[10.0, 10.0, 5.0]], (1_000_000, 1)), terrain(n=100)])
    ground = np.ones(len(xyz), bool)
    assert spikes.despike(xyz, ground)[:1_000_000].all()               # seconds, not hours


def test_a_chimney_and_a_multipath_point_go_the_ground_stays():
    xyz = terrain()
    xyz[10, 2] += 6.0                      # a chimney top kept as ground
    xyz[20, 2] -= 9.0                      # a multipath return under the terrain
    ground = np.ones(len(xyz), bool)
    out = spikes.despike(xyz, ground)
    assert not out[10] and not out[20]
    assert out.sum() == len(xyz) - 2


def test_a_steep_slope_is_no_spike():
    xyz = terrain(slope=0.45)              # 24 degrees, about SLOPE
    assert spikes.despike(xyz, np.ones(len(xyz), bool)).all()


def test_non_ground_and_tiny_inputs_are_left_as_they_are():
    xyz = terrain(n=20)
    xyz[:, 2] += np.arange(20) * 10.0      # nothing alike
    none = np.zeros(20, bool)
    assert not spikes.despike(xyz, none).any()
    few = np.zeros(20, bool)
    few[:spikes.NEIGHBOURS] = True          # k points or fewer: nothing to compare with
    np.testing.assert_array_equal(spikes.despike(xyz, few), few)
    assert spikes.despike(xyz, few) is not few


def brute_force_unstack(xyz, used, ground, *, cell_m, drop_m):
    """Each ground point against every used return of its own and the 8 cells around it."""
    lo = xyz[used | ground, :2].min(axis=0)
    cell = np.floor((xyz[:, :2] - lo) / cell_m).astype(int)
    out = ground.copy()
    for i in np.flatnonzero(ground):
        near = used & (np.abs(cell - cell[i]) <= 1).all(axis=1)
        if (xyz[near, 2] < xyz[i, 2] - drop_m).any():
            out[i] = False
    return out


@pytest.mark.parametrize("far", [False, True], ids=["box", "stray point"])   # a dense box of cells, or sorted cells
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_unstack_matches_brute_force_on_random_labels(seed, far):
    rng = np.random.default_rng(seed)
    xyz = terrain(seed=seed)
    xyz[rng.choice(400, 60, replace=False), 2] += rng.uniform(-12, 12, 60)
    ground = rng.random(400) < 0.7
    used = rng.random(400) < 0.9
    if far:                                     # a used return 30 km away: its box holds millions of cells
        xyz = np.concatenate([xyz, xyz[:1] + [30_000.0, 20_000.0, -50.0]])
        ground, used = np.append(ground, False), np.append(used, True)
    for cell_m, drop_m in [(1.0, 5.0), (3.0, 2.0), (7.5, 0.5)]:
        np.testing.assert_array_equal(spikes.unstack(xyz, used, ground, cell_m=cell_m, drop_m=drop_m),
                                      brute_force_unstack(xyz, used, ground, cell_m=cell_m, drop_m=drop_m))


def bridge(seed=0):
    """A 40 m wide valley 12 m deep, crossed by a 6 m wide deck at the banks' height, 2 points/m²."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 100, (20_000, 2))
    z = np.where(np.abs(xy[:, 0] - 50) < 20, 88.0, 100.0) + rng.normal(0, 0.03, len(xy))
    deck = (np.abs(xy[:, 0] - 50) < 20) & (np.abs(xy[:, 1] - 50) < 3) & (rng.random(len(xy)) < 0.8)
    z[deck] = 100.0 + rng.normal(0, 0.03, deck.sum())
    return np.column_stack([xy, z]), deck


def test_a_deck_over_its_valley_is_no_ground_the_banks_stay():
    xyz, deck = bridge()
    ground = np.ones(len(xyz), bool)            # a filter that kept the deck
    out = spikes.guard(xyz, np.ones(len(xyz), bool), ground, spacing_m=0.7, slope_p90=0.0)
    assert not out[deck].any()
    banks = np.abs(xyz[:, 0] - 50) >= 22        # two cells from the valley's edges (its walls go)
    assert out[banks].all()
    valley = (np.abs(xyz[:, 0] - 50) < 18) & (np.abs(xyz[:, 1] - 50) > 5)     # 2 m off its walls and the deck
    assert out[valley].all()


def test_a_steep_slope_is_not_stacked():
    xyz = terrain(n=4000, slope=1.2)            # 50 degrees, the terrain's own 90th percentile
    ground = np.ones(len(xyz), bool)
    cell_m = 1.6
    assert spikes.unstack(xyz, ground, ground, cell_m=cell_m, drop_m=spikes.stacked_drop_m(cell_m, 1.2)).all()
    assert spikes.stacked_drop_m(cell_m, 1.2) > 1.2 * 2 * np.sqrt(2) * cell_m   # more than the slope's fall over 3x3 cells


def test_unstack_leaves_labels_without_returns_alone():
    xyz = terrain(n=30)
    ground = np.ones(30, bool)
    assert spikes.unstack(xyz, np.zeros(30, bool), ground, cell_m=1.0, drop_m=1.0).all()
    assert not spikes.unstack(xyz, ground, np.zeros(30, bool), cell_m=1.0, drop_m=1.0).any()


@pytest.mark.parametrize("k", [1, 2, 7, 8])
def test_the_median_of_sorted_rows_is_the_partitioned_median(k):
    """despike reads the median distance off the KD-tree's sorted rows: the same values."""
    rows = np.sort(np.round(np.random.default_rng(k).exponential(2.0, (500, k)), 1), axis=1)   # ties
    np.testing.assert_array_equal(spikes._median_sorted_rows(rows), spikes._median_rows(rows))


@pytest.mark.parametrize("far", [False, True], ids=["box", "stray point"])
def test_unstack_a_slice_at_a_time_gives_the_same_labels(monkeypatch, far):
    """A survey's window is read a slice of points at a time: slices of 7 and of 64 points, and
    the corner's cells met in a later slice than the first, give the labels of one slice."""
    rng = np.random.default_rng(4)
    xyz = terrain(n=1000, seed=4)
    xyz[rng.choice(1000, 150, replace=False), 2] += rng.uniform(-12, 12, 150)
    ground, used = rng.random(1000) < 0.7, rng.random(1000) < 0.9
    xyz[-1, :2] = -3.0                                  # the corner's point last
    if far:
        xyz[-2, :2] += [30_000.0, 20_000.0]
    whole = spikes.unstack(xyz, used, ground, cell_m=1.5, drop_m=2.0)
    np.testing.assert_array_equal(whole, brute_force_unstack(xyz, used, ground, cell_m=1.5, drop_m=2.0))
    assert (ground & ~whole).sum() > 20                 # a real test: many points unmade
    for rows in (7, 64):
        monkeypatch.setattr(columns, "SLICE_ROWS", rows)
        np.testing.assert_array_equal(spikes.unstack(xyz, used, ground, cell_m=1.5, drop_m=2.0), whole)
