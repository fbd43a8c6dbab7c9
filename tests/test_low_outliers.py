"""The low-outlier detector on clouds whose answer is known, and the pre-step it makes of a
method's run: hidden from the method, non-ground, the same labels from Python and the CLI path."""
from __future__ import annotations

import numpy as np
import pytest

from gfjax import adaptive, low_outliers, methods
from gfjax.io import columns
from gfjax.io.cloud import Cloud, Points

ORIGIN = np.array([500_000.0, 5_000_000.0, 200.0])


def plane(size_m: float = 80.0, *, density: float = 2.0, slope: float = 0.0, seed: int = 0) -> np.ndarray:
    """Points `(n, 3)` spread at random over `size_m` squared, z = slope * x + 5 cm noise."""
    rng = np.random.default_rng(seed)
    n = int(size_m * size_m * density)
    xy = rng.uniform(0.0, size_m, (n, 2))
    z = slope * xy[:, 0] + rng.normal(0.0, 0.05, n)
    return np.column_stack([xy, z]) + ORIGIN


def detect(xyz: np.ndarray) -> np.ndarray:
    """The detector with the last-return spacing `gfjax.adaptive.measure` gives (single returns)."""
    used = np.ones(len(xyz), bool)
    return low_outliers.detect(xyz, used, last_spacing_m=adaptive.measure(xyz).last_spacing_m)


def test_a_few_points_far_below_a_plane_are_flagged():
    xyz = plane()
    below = np.array([100, 2000, 7000])
    xyz[below, 2] -= 20.0
    low = detect(xyz)
    np.testing.assert_array_equal(np.flatnonzero(low), below)


def test_a_cluster_of_five_low_points_is_flagged():
    xyz = plane(seed=1)
    cluster = ORIGIN + np.array([[40.0, 40.0, -15.0], [40.6, 40.2, -15.1], [41.1, 40.9, -14.8],
                                 [39.5, 41.2, -15.2], [40.3, 39.4, -14.9]])
    low = detect(np.vstack([xyz, cluster]))
    assert low[len(xyz):].all() and not low[:len(xyz)].any()


def test_stacked_outliers_in_one_cell_go_one_a_pass():
    xyz = plane(seed=2)
    stack = ORIGIN + np.array([[30.2, 30.3, -20.0 - 0.5 * i] for i in range(4)])
    low = detect(np.vstack([xyz, stack]))
    assert low[len(xyz):].all() and not low[:len(xyz)].any()


def test_a_deep_narrow_ditch_of_real_ground_is_kept():
    xyz = plane(seed=3)
    ditch = (np.abs(xyz[:, 0] - ORIGIN[0] - 40.0) < 1.0)        # 2 m wide, 5 m deep, along y
    xyz[ditch, 2] -= 5.0
    rng = np.random.default_rng(3)
    floor = np.column_stack([40.0 + rng.uniform(-1.0, 1.0, 300), rng.uniform(0.0, 80.0, 300),
                             rng.normal(-5.0, 0.05, 300)]) + ORIGIN   # densely sampled floor
    assert not detect(np.vstack([xyz, floor])).any()


def test_ground_under_canopy_is_kept():
    """Sparse ground returns (last) under a dense canopy 15-25 m up (first returns)."""
    rng = np.random.default_rng(4)
    size = 120.0
    ground = np.column_stack([rng.uniform(0, size, (int(0.15 * size * size), 2)), rng.normal(0.0, 0.05, int(0.15 * size * size))])
    canopy_xy = rng.uniform(0, size, (int(3.0 * size * size), 2))
    canopy = np.column_stack([canopy_xy, rng.uniform(15.0, 25.0, len(canopy_xy))])
    xyz = np.vstack([ground, canopy]) + ORIGIN
    is_ground = np.arange(len(xyz)) < len(ground)
    last_spacing = adaptive.measure(xyz, xyz[is_ground]).last_spacing_m
    low = low_outliers.detect(xyz, np.ones(len(xyz), bool), last_spacing_m=last_spacing)
    assert not (low & is_ground).any()


@pytest.mark.parametrize("slope", [0.5, 1.0, 1.4])
def test_a_steep_tilted_plane_has_no_outlier(slope):
    assert not detect(plane(slope=slope, seed=5)).any()


def test_used_points_only_and_an_empty_cloud():
    xyz = plane(seed=6)
    xyz[10, 2] -= 20.0
    used = np.ones(len(xyz), bool)
    used[10] = False                                          # noise: never flagged
    assert not low_outliers.detect(xyz, used, last_spacing_m=1.0).any()
    assert low_outliers.detect(np.zeros((0, 3)), np.zeros(0, bool), last_spacing_m=1.0).shape == (0,)


def test_a_stray_point_far_away_keeps_the_flags():
    """A box the points leave mostly empty runs on the occupied cells only, with the same answer."""
    xyz = plane(seed=7)
    xyz[[5, 500], 2] -= 20.0
    stray = ORIGIN + np.array([[90_000.0, 70_000.0, 0.0]])
    used = np.ones(len(xyz) + 1, bool)
    low = low_outliers.detect(np.vstack([xyz, stray]), used, last_spacing_m=1.0)
    np.testing.assert_array_equal(np.flatnonzero(low), [5, 500])


HIDING = [name for name in methods.names() if methods.get(name).hides_low_outliers]


@pytest.mark.parametrize("name", HIDING)
def test_hidden_points_are_non_ground_and_python_and_cli_agree(name):
    from gfjax.cli._common import MethodSetup

    xyz = plane(60.0, density=1.0, seed=8)
    below = np.array([50, 1200, 2500])
    xyz[below, 2] -= 20.0
    cloud = Cloud.from_xyz(xyz)
    method = methods.get(name)
    followed = method.filter(cloud, progress=False)
    python = np.asarray(followed.ground, bool)
    assert followed.settled.low_outliers == len(below)                 # said by `gfjax filter -v`
    assert f"low outliers hidden from it: {len(below)}" in followed.settled.describe()
    params = method.Params() if method.Params is not None else None
    cli = np.asarray(MethodSetup(method, method.Config(), params, None, frozenset()).filter(cloud, progress=False).ground,
                     bool)
    np.testing.assert_array_equal(python, cli)
    assert not python[below].any()
    assert python.sum() >= 0.95 * len(xyz)
    fixed = method.filter(cloud, config=method.Config(), params=params, progress=False)
    assert fixed.settled is None                               # fixed values: the method alone, no pre-step
    view = Points.of_xyz(xyz)
    assert adaptive.hide(view, adaptive.measure(xyz)) is not None


def test_fixed_values_run_the_method_alone():
    """`run` without a terrain is the filter's own result: nothing hidden, no guard."""
    from gfjax.result import Result

    xyz = plane(seed=9)
    xyz[3, 2] -= 20.0
    cloud = Cloud.from_xyz(xyz)
    seen = []

    def filter_fn(view, **_):
        seen.append(view.filter_mask("all").copy())
        return Result(ground=np.ones(len(xyz), bool))

    given = adaptive.run(filter_fn, cloud, None, config=None, params=None, hides_low_outliers=True)
    assert given.ground.all() and seen[-1].all()
    settled = adaptive.settle_cloud(lambda t: {}, cloud, methods.get("smrf").Config(), None)
    ran = adaptive.run(filter_fn, cloud, settled, config=None, params=None, hides_low_outliers=True)
    assert not seen[-1][3] and seen[-1].sum() == len(xyz) - 1          # hidden from the method
    assert not ran.ground[3]                                           # and non-ground
    adaptive.run(filter_fn, cloud, settled, config=None, params=None, hides_low_outliers=False)
    assert seen[-1].all()                                              # a method that does not hide


@pytest.mark.parametrize("origin", [None, ORIGIN[:2] - 7.3], ids=["points' corner", "frame's corner"])
def test_the_first_pass_a_slice_at_a_time_gives_the_same_flags(monkeypatch, origin):
    """A survey's window is read a slice of points at a time (the corner's point in the last
    slice, unused points among them): the flags of one slice, outliers or none."""
    xyz = plane(seed=8)
    used = np.random.default_rng(8).random(len(xyz)) > 0.1
    xyz[-1, :2] = ORIGIN[:2] - 0.4
    for sunk in ([], [3, 700, 701]):
        sunk_xyz = xyz.copy()
        sunk_xyz[sunk, 2] -= 25.0
        used[sunk] = True
        whole = low_outliers.detect(sunk_xyz, used, last_spacing_m=1.0, origin_m=origin)
        np.testing.assert_array_equal(np.flatnonzero(whole), sunk)
        for rows in (5, 333):
            monkeypatch.setattr(columns, "SLICE_ROWS", rows)
            np.testing.assert_array_equal(low_outliers.detect(sunk_xyz, used, last_spacing_m=1.0, origin_m=origin),
                                          whole)
            monkeypatch.undo()
