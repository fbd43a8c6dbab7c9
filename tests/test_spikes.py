"""The spike guard against a brute-force loop, and on clouds whose spikes are known."""
from __future__ import annotations

import numpy as np
import pytest

from gfjax import spikes


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
