"""MASF densification with batch insertions against a reference that re-triangulates all ground
points with Qhull before every test pass (the direct reading of Sec. 2.4)."""
from __future__ import annotations

import numpy as np
import pytest
from scene import hilly_town

from gfjax import masf
from gfjax.io.cloud import Cloud
from gfjax.masf.densify import buffer_cells, densify, low_seed_pits
from gfjax.masf.ground_tin import GroundTin
from gfjax.masf.tin import nearest_z


def reference_densify(points_m, seeds, layers, alphas_m, *, shape, cell_m, st, ft_m, layer_passes,
                      nearest_facet, retest_earlier):
    """Every pass tests every waiting point against a TIN triangulated from scratch."""
    seed_xyz = points_m[seeds]
    in_tin = layers[0].copy()
    top = np.flatnonzero(in_tin)
    in_tin[top[low_seed_pits(seed_xyz[top], drop_m=1.0, slope=1.0, cap_m=4.0)]] = False
    ring_xy = buffer_cells(shape, cell_m=cell_m)
    ring = np.column_stack([ring_xy, nearest_z(ring_xy, seed_xyz[in_tin])])
    threshold_m = np.full(len(seeds), -np.inf)
    threshold_m[layers[0] & in_tin] = st * alphas_m[0] + ft_m
    for level in range(1, len(alphas_m)):
        dt_m = st * alphas_m[level] + ft_m
        threshold_m[layers[level] & ~np.isfinite(threshold_m)] = dt_m
        for _ in range(layer_passes):
            waiting = (np.isfinite(threshold_m) if retest_earlier else layers[level]) & ~in_tin
            candidates = np.flatnonzero(waiting)
            limit_m = threshold_m[candidates] if retest_earlier else dt_m
            tin = GroundTin(np.concatenate([seed_xyz[in_tin], ring]))
            accepted = candidates[tin.distance_m(seed_xyz[candidates], nearest_facet=nearest_facet) < limit_m]
            in_tin[accepted] = True
            if len(accepted) == 0:
                break
    ground = np.zeros(len(points_m), dtype=bool)
    ground[seeds[in_tin]] = True
    tin = GroundTin(np.concatenate([seed_xyz[in_tin], ring]))
    rest = np.flatnonzero(~ground)
    ground[rest[tin.distance_m(points_m[rest], nearest_facet=nearest_facet) < ft_m]] = True
    return ground, in_tin


@pytest.fixture(scope="module", params=[0, 7], ids=["hilly0", "hilly7"])
def inputs(request):
    """Densification inputs of a hilly synthetic town (the filter's own stages up to the layers)."""
    xyz, _, _ = hilly_town(seed=request.param)
    _, diag = masf.filter_points(xyz, masf.Config(), masf.Params())
    return xyz - diag.origin_m, diag


@pytest.mark.parametrize("layer_passes, nearest_facet, retest_earlier",
                         [(1, False, False), (3, False, False), (8, False, False), (3, True, False), (3, False, True)])
def test_densify_matches_full_retriangulation(inputs, layer_passes, nearest_facet, retest_earlier):
    local, diag = inputs
    kw = dict(shape=diag.bottom_z_m.shape, cell_m=1.0, st=0.05, ft_m=0.5, layer_passes=layer_passes,
              nearest_facet=nearest_facet, retest_earlier=retest_earlier)
    got = densify(local, diag.potential_ground, diag.layers, diag.alphas_m, **kw)
    ground, in_tin = reference_densify(local, diag.potential_ground, diag.layers, diag.alphas_m, **kw)
    assert got.tin_rebuilds == 0
    np.testing.assert_array_equal(got.seed_ground, in_tin)
    np.testing.assert_array_equal(got.ground, ground)
    assert got.added_per_layer.sum() == in_tin.sum()
    qhull_path = densify(local, diag.potential_ground, diag.layers, diag.alphas_m, retriangulate=True, **kw)
    np.testing.assert_array_equal(qhull_path.ground, ground)



def test_the_scene_needs_retests(inputs):
    """Guard for the test above: on this scene extra passes accept points (pass 2 has work)."""
    local, diag = inputs
    kw = dict(shape=diag.bottom_z_m.shape, cell_m=1.0, st=0.05, ft_m=0.5)
    one = densify(local, diag.potential_ground, diag.layers, diag.alphas_m, layer_passes=1, **kw)
    three = densify(local, diag.potential_ground, diag.layers, diag.alphas_m, layer_passes=3, **kw)
    assert (one.seed_ground != three.seed_ground).sum() >= 10


def test_filter_reference_path_gives_the_same_labels():
    xyz, truth, _ = hilly_town(seed=3, size_m=40.0)
    cloud = Cloud.from_xyz(xyz)
    fast = masf.filter(cloud)
    reference = masf.filter(cloud, config=masf.Config(retriangulate=True))
    np.testing.assert_array_equal(fast.ground, reference.ground)
    assert fast.diagnostics.tin_rebuilds == 0 and fast.ground[truth].mean() > 0.9
