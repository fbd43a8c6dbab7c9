"""`gfjax.smrf.filter` end to end: synthetic scenes, ignored points, options, ISPRS accuracy."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import gfjax
from gfjax import metrics
from gfjax.data import demo_sample
from gfjax.errors import InputError
from gfjax.io.cloud import Cloud
from gfjax.smrf import PRESETS, Config, Params
from gfjax.smrf import filter as smrf_filter

SMALL = Config(window_m=6.0)


def town(seed=0, size_m=48):
    """Sloped ground (5 %), 1.5 points per m^2, one 10 x 8 m building 7 m tall, a tree-like
    cluster, and one low outlier 20 m below ground. Returns xyz (n, 3) and the truth."""
    rng = np.random.default_rng(seed)
    n = int(1.5 * size_m * size_m)
    xy = rng.uniform(0, size_m, (n, 2))
    z = 100 + 0.05 * xy[:, 0] + rng.normal(0, 0.03, n)
    building = (xy[:, 0] > 20) & (xy[:, 0] < 30) & (xy[:, 1] > 10) & (xy[:, 1] < 18)
    z[building] += 7.0
    tree = np.hypot(xy[:, 0] - 12, xy[:, 1] - 35) < 2.5
    z[tree] += rng.uniform(3, 9, tree.sum())
    ground = ~(building | tree)
    outlier = np.flatnonzero(ground)[7]
    z[outlier] -= 20.0
    ground[outlier] = False
    return np.column_stack([xy + [500_000.0, 5_400_000.0], z]), ground


@pytest.fixture(scope="module")
def scene():
    return town()


@pytest.fixture(scope="module")
def labels(scene):
    return smrf_filter(Cloud.from_xyz(scene[0]), config=SMALL)


def test_town_building_tree_and_outlier(scene, labels):
    _, truth = scene
    m = metrics.point_metrics(labels.ground, truth)
    assert m["total_error"] < 0.02 and m["kappa"] > 0.9
    assert not labels.ground[~truth].any()                 # no building, tree or outlier point is ground
    d = labels.diagnostics
    assert d.zimin.shape == d.zipro.shape == d.object_cells.shape == (48, 48)
    assert d.object_cells.sum() >= 60 and d.low_outliers.sum() == 1
    assert abs(float(np.median(d.zipro)) - 101.2) < 0.5    # absolute heights in the cloud's frame


def test_ignored_points_are_never_ground(scene, labels):
    xyz, _ = scene
    cls = np.full(len(xyz), 2, np.uint8)
    cls[::5] = 7                                            # noise
    cloud = Cloud.from_xyz(xyz, classification=cls)
    result = smrf_filter(cloud, config=SMALL)
    assert not result.ground[::5].any()
    assert result.ground.shape == (len(xyz),)
    assert np.mean(result.ground[cls != 7] == labels.ground[cls != 7]) > 0.99


def test_last_returns_only(scene):
    xyz, _ = scene
    cloud = Cloud.from_xyz(xyz)
    n = len(xyz)
    cloud.las.number_of_returns = np.full(n, 2, np.uint8)
    cloud.las.return_number = np.where(np.arange(n) % 2 == 0, 1, 2).astype(np.uint8)
    result = smrf_filter(cloud, config=SMALL, returns="last")
    assert not result.ground[::2].any() and result.ground[1::2].mean() > 0.7


def test_edge_cases_one_point_and_empty():
    one = smrf_filter(Cloud.from_xyz(np.array([[10.0, 20.0, 5.0]])), config=SMALL)
    np.testing.assert_array_equal(one.ground, [True])
    flat = smrf_filter(Cloud.from_xyz(np.array([[0.0, 0.0, 1.0], [0.2, 0.3, 1.0], [0.5, 0.1, 1.0]])), config=SMALL)
    assert flat.ground.all()
    cloud = Cloud.from_xyz(np.array([[0.0, 0.0, 1.0]]), classification=np.array([7], np.uint8))
    assert not smrf_filter(cloud, config=SMALL).ground.any()


def test_bad_options():
    with pytest.raises(ValueError, match="cell_m must be > 0"):
        Config(cell_m=-1.0)
    with pytest.raises(ValueError, match="inpaint"):
        Config(inpaint="splines")
    cloud = Cloud.from_xyz(np.zeros((2, 3)))
    with pytest.raises(InputError, match="slope"):
        smrf_filter(cloud, params=Params(slope=-0.1))
    with pytest.raises(InputError, match="returns"):
        smrf_filter(cloud, returns="first")


def test_params_are_traced():
    params = dataclasses.replace(Params(), slope=0.3)
    assert params.slope.dtype == np.float32 and float(params.slope) == pytest.approx(0.3)


def test_nearest_fill_preset(scene, labels):
    config = dataclasses.replace(SMALL, **PRESETS["nearest-fill"])
    result = smrf_filter(Cloud.from_xyz(scene[0]), config=config)
    assert np.mean(result.ground == labels.ground) > 0.98
    assert metrics.point_metrics(result.ground, scene[1])["total_error"] < 0.03


def _sample(name):
    if name == "samp12":
        return demo_sample()                                # shipped in gfjax: runs everywhere
    from conftest import shared_file
    return shared_file(f"isprs_filtertest/reference/{name}-utm.laz")


# Measured with the defaults (experiments/results/smrf_isprs.md): samp12 2.97 % / kappa 0.941,
# samp24 4.00 % / 0.899. Thresholds keep a margin.
@pytest.mark.parametrize("name,max_total_error,min_kappa", [
    ("samp12", 0.04, 0.9), pytest.param("samp24", 0.055, 0.85, marks=pytest.mark.data)])
def test_isprs_accuracy_defaults(name, max_total_error, min_kappa):
    cloud = gfjax.read(_sample(name))
    result = smrf_filter(cloud)
    m = metrics.point_metrics(result.ground, cloud.classification == 2)
    assert m["total_error"] <= max_total_error and m["kappa"] >= min_kappa, m
