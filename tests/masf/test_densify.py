"""MASF densification with batch insertions against a reference that re-triangulates all ground
points with Qhull before every test pass (the direct reading of Sec. 2.4)."""
from __future__ import annotations

import numpy as np
import pytest
from scene import hilly_town
from scipy.spatial import cKDTree

from gfjax import masf
from gfjax.io.cloud import Cloud
from gfjax.masf.densify import BUFFER_MAX_SLOPE, buffer_cells, buffer_z, densify, low_seed_pits
from gfjax.masf.ground_tin import GroundTin
from gfjax.masf.tin import nearest_z


def reference_densify(points_m, seeds, layers, alphas_m, *, shape, cell_m, st, ft_m, layer_passes,
                      nearest_facet, retest_earlier, buffer_heights="top", mirror_max_m=None):
    """Every pass tests every waiting point against a TIN triangulated from scratch."""
    seed_xyz = points_m[seeds]
    in_tin = layers[0].copy()
    top = np.flatnonzero(in_tin)
    in_tin[top[low_seed_pits(seed_xyz[top], drop_m=1.0, slope=1.0, cap_m=4.0)]] = False
    ring_xy = buffer_cells(shape, cell_m=cell_m)
    ring = np.column_stack([ring_xy, nearest_z(ring_xy, seed_xyz[in_tin])])

    def lift():
        if buffer_heights != "top":
            tin = GroundTin(np.concatenate([seed_xyz[in_tin], ring]))
            ring[:, 2] = buffer_z(tin, in_tin.sum() + np.arange(len(ring)), extrapolate=buffer_heights == "extrapolated")

    threshold_m = np.full(len(seeds), -np.inf)
    threshold_m[layers[0] & in_tin] = st * alphas_m[0] + ft_m
    direct = in_tin.copy()          # joined by their own distance: the mirror's centres
    for level in range(1, len(alphas_m)):
        lift()
        dt_m = st * alphas_m[level] + ft_m
        threshold_m[layers[level] & ~np.isfinite(threshold_m)] = dt_m
        for _ in range(layer_passes):
            waiting = (np.isfinite(threshold_m) if retest_earlier else layers[level]) & ~in_tin
            candidates = np.flatnonzero(waiting)
            limit_m = threshold_m[candidates] if retest_earlier else dt_m
            tin = GroundTin(np.concatenate([seed_xyz[in_tin], ring]))
            own, facet = tin.measure(seed_xyz[candidates], nearest_facet=nearest_facet)
            distance = own
            if mirror_max_m is not None:
                centre_ok = np.concatenate([direct[in_tin], np.zeros(len(ring), dtype=bool)])
                image, _ = tin.mirrored(seed_xyz[candidates], facet, centre_ok, nearest_facet=nearest_facet)
                distance = np.where(own < mirror_max_m, np.minimum(own, image), own)
            accepted = candidates[distance < limit_m]
            direct[accepted] = (own < limit_m)[distance < limit_m]
            in_tin[accepted] = True
            if len(accepted) == 0:
                break
    lift()
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


@pytest.mark.parametrize("layer_passes, nearest_facet, retest_earlier, buffer_heights, mirror_max_m",
                         [(1, False, False, "top", None), (3, False, False, "top", None),
                          (8, False, False, "top", None), (3, True, False, "top", None),
                          (3, False, True, "top", None), (3, False, False, "nearest", None),
                          (3, False, False, "extrapolated", None), (3, False, False, "extrapolated", 1.5),
                          (8, True, True, "extrapolated", 3.0)])
def test_densify_matches_full_retriangulation(inputs, layer_passes, nearest_facet, retest_earlier, buffer_heights,
                                              mirror_max_m):
    local, diag = inputs
    kw = dict(shape=diag.bottom_z_m.shape, cell_m=1.0, st=0.05, ft_m=0.5, layer_passes=layer_passes,
              nearest_facet=nearest_facet, retest_earlier=retest_earlier, buffer_heights=buffer_heights,
              mirror_max_m=mirror_max_m)
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
    fast = masf.filter(cloud, config=masf.Config())
    reference = masf.filter(cloud, config=masf.Config(retriangulate=True))
    np.testing.assert_array_equal(fast.ground, reference.ground)
    assert fast.diagnostics.tin_rebuilds == 0 and fast.ground[truth].mean() > 0.9


def _plane_tin(slope_x, slope_y, *, ring_z=-5.0):
    """A TIN of ground points on `z = slope_x x + slope_y y` inside a 20 m square, with its ring of
    buffer cells at `ring_z` (vertex ids after the ground points)."""
    rng = np.random.default_rng(1)
    xy = rng.uniform(1.0, 19.0, (200, 2))
    ground = np.column_stack([xy, slope_x * xy[:, 0] + slope_y * xy[:, 1]])
    ring_xy = buffer_cells((20, 20), cell_m=1.0)
    tin = GroundTin(np.concatenate([ground, np.column_stack([ring_xy, np.full(len(ring_xy), ring_z)])]))
    return tin, ground, len(ground) + np.arange(len(ring_xy)), ring_xy


def test_buffer_heights_continue_a_plane():
    tin, ground, ring, ring_xy = _plane_tin(0.3, -0.5)
    np.testing.assert_allclose(buffer_z(tin, ring, extrapolate=True), 0.3 * ring_xy[:, 0] - 0.5 * ring_xy[:, 1],
                               atol=1e-9)
    np.testing.assert_array_equal(buffer_z(tin, ring, extrapolate=False), nearest_z(ring_xy, ground))


def test_buffer_heights_carry_at_most_the_slope_cap():
    tin, ground, ring, ring_xy = _plane_tin(0.0, 3.0)
    _, near = cKDTree(ground[:, :2]).query(ring_xy)
    offset = ring_xy - ground[near, :2]
    rise = buffer_z(tin, ring, extrapolate=True) - ground[near, 2]
    np.testing.assert_allclose(rise, np.clip(3.0 * offset[:, 1], -BUFFER_MAX_SLOPE * np.hypot(*offset.T),
                                             BUFFER_MAX_SLOPE * np.hypot(*offset.T)), atol=1e-9)


def test_with_heights_moves_only_the_named_vertices():
    tin, ground, ring, _ = _plane_tin(0.1, 0.2)
    lifted = tin.with_heights(ring, np.full(len(ring), 7.0))
    np.testing.assert_array_equal(lifted.simplices, tin.simplices)
    np.testing.assert_array_equal(lifted.xyz_m[ring, 2], 7.0)
    np.testing.assert_array_equal(lifted.xyz_m[:len(ground)], tin.xyz_m[:len(ground)])
    assert (tin.xyz_m[ring, 2] == -5.0).all()


@pytest.mark.parametrize("slope", [0.6, 1.0])
def test_ground_rising_to_the_edge_is_kept_with_extrapolated_buffer_heights(slope):
    """A plane rising to the north edge: large balls cannot touch its upper band (their centres
    fall outside the hull), so the top layer ends metres below the edge. Buffer points at the
    height of the nearest top-layer point pin a flat TIN there and reject the band; carried up
    the slope, they keep every point."""
    rng = np.random.default_rng(0)
    g = np.arange(0.0, 60.0) + 0.25
    x, y = (a.ravel() + rng.uniform(-0.2, 0.2, a.size) for a in np.meshgrid(g, g))
    xyz = np.column_stack([x, y, slope * y + 0.02 * np.sin(x)])
    fixed, _ = masf.filter_points(xyz, masf.Config(buffer_heights="top", mirror_max_m=None), masf.Params())
    carried, _ = masf.filter_points(xyz, masf.Config(buffer_heights="extrapolated", mirror_max_m=None), masf.Params())
    assert (~fixed).sum() > 100 and y[~fixed].min() > 40.0          # the upper band only
    assert carried.all()


def test_mirror_image_continues_the_slope_and_drops_an_object_below_the_ground():
    """A slope z = 0.5 x up to x = 10 m in the TIN: a point beyond its upper edge on the same
    slope has its image through the nearest corner on the slope (distance 0); a point 2 m above
    flat ground has its image 2 m below it."""
    g = np.arange(0.0, 11.0)
    x, y = (a.ravel() for a in np.meshgrid(g, np.arange(0.0, 21.0)))
    slope = np.column_stack([x, y, 0.5 * x])
    far = np.column_stack([np.full(21, 20.0), np.arange(0.0, 21.0), np.full(21, 5.0)])   # a flat top, 10 m on
    tin = GroundTin(np.concatenate([slope, far]))
    beyond = np.array([[10.4, 10.3, 5.2], [10.6, 4.7, 5.3]])
    direct, facet = tin.measure(beyond)
    image, image_facet = tin.mirrored(beyond, facet, np.ones(len(tin.xyz_m), dtype=bool))
    assert (direct > 0.15).all() and (image_facet >= 0).all()
    np.testing.assert_allclose(image, 0.0, atol=1e-9)
    flat = GroundTin(np.column_stack([x, y, np.zeros_like(x)]))
    car = np.array([[4.3, 7.6, 2.0]])
    _, facet = flat.measure(car)
    np.testing.assert_allclose(flat.mirrored(car, facet, np.ones(len(flat.xyz_m), dtype=bool))[0], 2.0)
    assert flat.mirrored(car, facet, np.zeros(len(flat.xyz_m), dtype=bool))[0][0] == np.inf   # no centre allowed
