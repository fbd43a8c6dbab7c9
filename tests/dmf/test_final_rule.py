"""DMF step 7 readings (Wu et al. 2025, Sec. 2.6): the height threshold in multiples of W, the
lowest-point support elevation and the combined rule, on the shrub scene (flat ground under a
patch of understory 0.45 m high; W = 1 m) whose answer is known."""
from __future__ import annotations

import dmf_scenes as scenes
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax import dmf
from gfjax.dmf import extract


@pytest.fixture(scope="session")
def shrub():
    """`(shrub flag, local points, diagnostics)` of the default filter on the shrub scene."""
    cloud, shrub = scenes.shrub_scene()
    d = dmf.filter(cloud).diagnostics
    return shrub, cloud.xyz_m - d.origin_m, d


def _ground(shrub, config, params):
    _, local, d = shrub
    nodes, ground, _ = extract.extract_ground(local, d.voxels, d.ngnem_rc.reshape(-1), d.in_ndng, config, params)
    return nodes, ground


def test_threshold_is_affine_in_w_and_traced():
    params = dmf.Params(height_threshold_m=0.1, height_threshold_w=0.2)
    assert params.threshold_m(3.0).dtype == jnp.float32
    np.testing.assert_allclose(float(params.threshold_m(3.0)), 0.7, rtol=1e-6)
    np.testing.assert_allclose(float(jax.jit(lambda p: p.threshold_m(3.0))(params)), 0.7, rtol=1e-6)
    grad = jax.grad(lambda p: p.threshold_m(3.0))(params)          # tunable: both parts carry a gradient
    assert float(grad.height_threshold_m) == 1.0 and float(grad.height_threshold_w) == 3.0


def test_default_rejects_the_understory_and_keeps_the_ground(shrub):
    """Default: the height rule at 0.2 W = 0.2 m; the understory stands 0.45 m high."""
    flag, _, d = shrub
    cloud, _ = scenes.shrub_scene()
    result = dmf.filter(cloud)
    assert float(dmf.Params().threshold_m(d.cell_m)) == pytest.approx(0.2)
    assert d.cell_m == 1.0 and not d.ngnem_rc.any()                 # no object: all cells TP_G
    assert not result.ground[flag].any() and result.ground[~flag].all()


def test_threshold_in_w_equals_the_same_threshold_in_metres(shrub):
    flag = shrub[0]
    config = dmf.Config()
    _, in_w = _ground(shrub, config, dmf.Params(height_threshold_m=0.0, height_threshold_w=0.25))
    _, in_m = _ground(shrub, config, dmf.Params(height_threshold_m=0.25, height_threshold_w=0.0))
    np.testing.assert_array_equal(in_w, in_m)                       # W = 1 m
    assert not in_w[flag].any() and in_w[~flag].all()
    _, high = _ground(shrub, config, dmf.Params(height_threshold_m=0.0, height_threshold_w=0.6))
    assert high.all()                                               # 0.6 W is above the understory


def test_column_lowest_z_matches_a_loop():
    from gfjax.dmf import voxels
    rng = np.random.default_rng(7)
    xyz = np.column_stack([rng.uniform(0, 9, 300), rng.uniform(0, 7, 300), rng.uniform(0, 5, 300)])
    vox = voxels.bin_voxels(xyz, 2.0)
    lowest = extract.column_lowest_z(xyz, vox)
    for node, cell in enumerate(vox.cell):
        assert lowest[node] == xyz[vox.point_cell == cell, 2].min()


def test_lowest_support_elevation_is_the_lower_envelope(shrub):
    """A centroid sits 0.11 m above the ground where its cell holds understory, so at 0.38 m
    the centroid surface takes some understory as ground and the lowest-point surface none."""
    flag, local, d = shrub
    low_nodes, low = _ground(shrub, dmf.Config(support_elevation="lowest"), dmf.Params(height_threshold_m=0.38,
                                                                                         height_threshold_w=0.0))
    own = low_nodes.from_ndng
    np.testing.assert_array_equal(low_nodes.z_surface[own], extract.column_lowest_z(local, d.voxels)[own])
    np.testing.assert_array_equal(low_nodes.xyz[:, 2], low_nodes.z_surface - 2.0 * d.cell_m)
    _, centroid = _ground(shrub, dmf.Config(), dmf.Params(height_threshold_m=0.38, height_threshold_w=0.0))
    assert centroid[flag].mean() > 0.2 and not low[flag].any()
    assert centroid[~flag].all() and low[~flag].all()


def test_both_rules_is_the_intersection(shrub):
    flag = shrub[0]
    params = dmf.Params(height_threshold_m=0.0, height_threshold_w=0.6)
    _, both = _ground(shrub, dmf.Config(final_rule="both"), params)
    _, nearest = _ground(shrub, dmf.Config(final_rule="m_nearest"), params)
    _, height = _ground(shrub, dmf.Config(final_rule="height"), params)
    np.testing.assert_array_equal(both, nearest & height)
    assert height[flag].all() and not both[flag].any()              # the M-nearest rule drops the understory
    assert 0.8 < both[~flag].mean() < 1.0                           # and some ground (Sec. 5.2)


def test_bad_readings_are_rejected():
    with pytest.raises(ValueError, match="support_elevation"):
        dmf.Config(support_elevation="median")
    with pytest.raises(ValueError, match="final_rule"):
        dmf.Config(final_rule="either")
