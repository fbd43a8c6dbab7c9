"""MASF preprocessing: extended local minimum per cell, low-outlier neighbourhood test."""
from __future__ import annotations

import numpy as np
import pytest

from gfjax.masf.preprocess import grid_shape, potential_ground

KW = dict(grid_m=1.0, outlier_gap_m=1.0, neighbour_drop_m=1.0)


def brute_force_cell_choice(xyz, grid_m, gap_m):
    """Per cell, sort by z (ties by y, x) and walk up: the first point whose gap to the next
    point of the cell is <= gap_m (or the top point) is the potential ground point."""
    h, w = grid_shape(xyz[:, :2], grid_m=grid_m)
    chosen = {}
    cells = {}
    for i, (x, y, _) in enumerate(xyz):
        key = (h - 1 - int(np.floor(y / grid_m)), int(np.floor(x / grid_m)))
        cells.setdefault(key, []).append(i)
    for key, members in cells.items():
        members.sort(key=lambda i: (xyz[i, 2], xyz[i, 1], xyz[i, 0]))
        for pos, i in enumerate(members):
            if pos == len(members) - 1 or xyz[members[pos + 1], 2] - xyz[i, 2] <= gap_m:
                chosen[key] = i
                break
    return chosen


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gap_rule_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 6, (300, 2))
    z = rng.choice([0.0, 0.5, 3.0, 8.0], 300) + rng.normal(0, 0.2, 300)
    xyz = np.column_stack([xy, z])
    # a huge drop threshold switches the neighbourhood test off
    pre = potential_ground(xyz, grid_m=1.0, outlier_gap_m=1.0, neighbour_drop_m=1e9)
    expected = brute_force_cell_choice(xyz, 1.0, 1.0)
    got = {(int(r), int(c)): int(i) for r, c, i in zip(pre.row, pre.col, pre.index)}
    assert got == expected


def test_point_order_does_not_change_the_choice():
    rng = np.random.default_rng(3)
    xyz = np.column_stack([rng.uniform(0, 8, (400, 2)), rng.integers(0, 4, 400) * 0.5])  # many z ties
    pre = potential_ground(xyz, **KW)
    perm = rng.permutation(len(xyz))
    pre_perm = potential_ground(xyz[perm], **KW)
    assert sorted(map(tuple, xyz[pre.index])) == sorted(map(tuple, xyz[perm][pre_perm.index]))


def flat_grid(size=9, z=10.0):
    g = np.arange(size) + 0.5
    xx, yy = np.meshgrid(g, g)
    return np.column_stack([xx.ravel(), yy.ravel(), np.full(size * size, z)])


def test_isolated_low_point_is_removed_but_a_slope_is_kept():
    xyz = flat_grid()
    low = 40                                   # the centre cell (4, 4)
    xyz[low, 2] -= 5.0
    pre = potential_ground(xyz, **KW)
    assert low not in set(pre.index) and len(pre.index) == len(xyz) - 1
    assert pre.neighbour_outliers.sum() == 1
    slope = flat_grid()
    slope[:, 2] = 0.9 * slope[:, 0]            # 0.9 m per cell: never more than 1 m below all neighbours
    assert len(potential_ground(slope, **KW).index) == len(slope)


def test_ground_under_canopy_is_kept_without_the_neighbour_test():
    """A sparse forest: one ground return among cells that hold canopy returns alone. The
    neighbourhood test takes it for a low outlier; without the test it stays."""
    canopy = flat_grid(z=15.0)
    ground = 40
    canopy[ground, 2] = 0.0
    assert ground not in set(potential_ground(canopy, **KW).index)
    pre = potential_ground(canopy, **KW, neighbour_test=False)
    assert ground in set(pre.index) and len(pre.index) == len(canopy) and not pre.neighbour_outliers.any()


def test_single_cell_outlier_below_a_cell_partner_is_skipped():
    xyz = np.array([[0.5, 0.5, -3.0], [0.6, 0.4, 5.0], [0.7, 0.2, 5.2]])
    pre = potential_ground(xyz, grid_m=1.0, outlier_gap_m=1.0, neighbour_drop_m=1.0)
    assert list(pre.index) == [1] and pre.gap_outliers == 1


def test_empty_input():
    pre = potential_ground(np.zeros((0, 3)), **KW)
    assert len(pre.index) == 0 and pre.shape == (1, 1)
