"""HAG targets: TIN of the labelled ground, nearest-ground extrapolation, the six bins."""
from __future__ import annotations

import numpy as np
import pytest

from gfjax.errors import InputError
from gfjax.sparsegf import HAG_BIN_EDGES_M, N_HAG_BINS, ground_surface, hag_bins, hag_targets

ORIGIN = np.array([512_000.0, 5_400_000.0, 250.0])


def plane(xy):
    return 0.1 * xy[:, 0] - 0.05 * xy[:, 1] + 3.0


def test_bins_by_hand():
    hag = np.array([-0.5, 0.0, 0.1, 0.2, 0.2001, 0.5, 0.7, 1.0, 2.0, 3.0, 3.5, 40.0])
    expected = [1, 1, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5]
    np.testing.assert_array_equal(hag_bins(hag, np.zeros(len(hag), bool)), expected)
    np.testing.assert_array_equal(hag_bins(hag, np.ones(len(hag), bool)), np.zeros(len(hag)))
    assert len(HAG_BIN_EDGES_M) + 2 == N_HAG_BINS


def test_heights_above_a_planar_ground_are_exact():
    rng = np.random.default_rng(0)
    g_xy = np.concatenate([rng.uniform(0, 100, (200, 2)), [[0, 0], [100, 0], [0, 100], [100, 100]]])
    o_xy = rng.uniform(1, 99, (300, 2))
    height = rng.choice([-0.3, 0.1, 0.35, 0.8, 2.0, 7.5], size=len(o_xy))
    xyz = np.concatenate([np.c_[g_xy, plane(g_xy)], np.c_[o_xy, plane(o_xy) + height]]) + ORIGIN
    cls = np.r_[np.full(len(g_xy), 2), rng.choice([0, 1, 5, 6, 7, 9, 18], size=len(o_xy))]
    out = hag_targets(xyz, cls)
    np.testing.assert_allclose(out.hag_m, np.r_[np.zeros(len(g_xy)), height], atol=1e-6)
    np.testing.assert_array_equal(out.ground, cls == 2)
    by_hand = {-0.3: 1, 0.1: 1, 0.35: 2, 0.8: 3, 2.0: 4, 7.5: 5}
    expected = np.r_[np.zeros(len(g_xy)), [by_hand[h] for h in height]]
    np.testing.assert_array_equal(out.bins, expected)
    assert out.bins.dtype == np.int32


def test_barycentric_interpolation_in_one_triangle():
    g = np.array([[0.0, 0.0, 10.0], [10.0, 0.0, 20.0], [0.0, 10.0, 40.0]])
    p = np.array([[2.0, 3.0]])                        # barycentric weights (0.5, 0.2, 0.3)
    np.testing.assert_allclose(ground_surface(g, p), [0.5 * 10 + 0.2 * 20 + 0.3 * 40])


def test_outside_the_hull_takes_the_nearest_ground_height():
    g = np.array([[0.0, 0.0, 1.0], [10.0, 0.0, 2.0], [0.0, 10.0, 3.0], [10.0, 10.0, 4.0]])
    others = np.array([[30.0, 11.0, 9.0], [-5.0, -5.0, 0.5], [-20.0, 9.0, 3.1]])
    out = hag_targets(np.concatenate([g, others]) + ORIGIN, np.array([2, 2, 2, 2, 1, 18, 7]))
    np.testing.assert_allclose(out.hag_m[4:], [9.0 - 4.0, 0.5 - 1.0, 3.1 - 3.0], atol=1e-9)
    np.testing.assert_array_equal(out.bins, [0, 0, 0, 0, 5, 1, 1])   # below ground -> bin 1


def test_ground_points_are_bin_0_even_off_the_surface():
    g = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [3.0, 3.0, 5.0], [3.0, 3.0, 0.0]])
    out = hag_targets(g, np.full(5, 2))
    np.testing.assert_array_equal(out.bins, np.zeros(5))


@pytest.mark.parametrize("ground", [np.array([[0.0, 0.0, 1.0]]),
                                    np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 2.0], [2.0, 2.0, 3.0]])],
                         ids=["one_point", "collinear"])
def test_degenerate_ground_falls_back_to_nearest(ground):
    other = np.array([[2.2, 1.9, 10.0], [-1.0, 0.0, 1.1]])
    out = hag_targets(np.concatenate([ground, other]), np.r_[np.full(len(ground), 2), [1, 1]])
    nearest = ground[np.argmin(np.hypot(*(ground[None, :, :2] - other[:, None, :2]).transpose(2, 0, 1)), axis=1)]
    np.testing.assert_allclose(out.hag_m[len(ground):], other[:, 2] - nearest[:, 2])


def test_no_ground_raises():
    with pytest.raises(InputError, match="no ground"):
        hag_targets(np.zeros((3, 3)), np.array([1, 0, 7]))


@pytest.mark.parametrize("xyz, cls, match", [(np.zeros((3, 2)), np.full(3, 2), "shape"),
                                             (np.zeros((3, 3)), np.full(4, 2), "classification"),
                                             (np.array([[0, 0, np.inf]]), np.full(1, 2), "non-finite")])
def test_bad_input_raises(xyz, cls, match):
    with pytest.raises(InputError, match=match):
        hag_targets(xyz, cls)
