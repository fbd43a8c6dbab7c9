"""MASF's densification TIN: point location, point-to-TIN distances, batch insertion against Qhull."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull, Delaunay

from gfjax.masf.ground_tin import GroundTin, point_triangle_distance

BOX = np.array([[-1.0, -1.0], [101.0, -1.0], [101.0, 101.0], [-1.0, 101.0]])


def with_z(xy, rng=None):
    z = np.zeros(len(xy)) if rng is None else rng.normal(0, 1, len(xy))
    return np.column_stack([xy, z])


def triangle_set(simplices):
    return set(map(tuple, np.sort(simplices, axis=1).tolist()))


def assert_valid_triangulation(t: GroundTin):
    """Counter-clockwise triangles tiling the hull, symmetric neighbours across shared edges,
    a triangle for every vertex, and the empty-circumcircle property (brute force)."""
    xy, simp, nbr = t.xyz_m[:, :2], t.simplices, t.neighbours
    corners = xy[simp]
    area2 = ((corners[:, 1, 0] - corners[:, 0, 0]) * (corners[:, 2, 1] - corners[:, 0, 1])
             - (corners[:, 1, 1] - corners[:, 0, 1]) * (corners[:, 2, 0] - corners[:, 0, 0]))
    assert (area2 > 0).all()
    np.testing.assert_allclose(area2.sum() / 2, ConvexHull(xy).volume, rtol=1e-12)
    for j in range(3):
        has = nbr[:, j] >= 0
        me, other = np.flatnonzero(has), nbr[has, j]
        edge = np.sort(simp[me][:, [(j + 1) % 3, (j + 2) % 3]], axis=1)
        back = nbr[other] == me[:, None]
        assert (back.sum(axis=1) == 1).all()
        opposite_side = np.argmax(back, axis=1)
        shared = np.sort(np.stack([simp[other, (opposite_side + 1) % 3], simp[other, (opposite_side + 2) % 3]], 1), axis=1)
        np.testing.assert_array_equal(edge, shared)
    assert (simp[t.vertex_to_simplex] == np.arange(len(xy))[:, None]).any(axis=1).all()
    centre_d = corners - corners[:, :1]
    a, b = centre_d[:, 1], centre_d[:, 2]
    d = 2 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    ux = (b[:, 1] * (a ** 2).sum(1) - a[:, 1] * (b ** 2).sum(1)) / d
    uy = (a[:, 0] * (b ** 2).sum(1) - b[:, 0] * (a ** 2).sum(1)) / d
    centre = corners[:, 0] + np.column_stack([ux, uy])
    radius = np.hypot(ux, uy)
    gap = np.linalg.norm(xy[None, :, :] - centre[:, None, :], axis=2) - radius[:, None]
    assert gap.min() > -1e-9 * radius.max()


def contains(corners, q, tol=1e-9):
    """Brute force: bool `(q, t)`, triangle `(t, 3, 2)` (counter-clockwise) holds point `q` `(q, 2)`."""
    a, b = corners[None, :, :, :], np.roll(corners, -1, axis=1)[None]
    cross = ((b[..., 0] - a[..., 0]) * (q[:, None, None, 1] - a[..., 1])
             - (b[..., 1] - a[..., 1]) * (q[:, None, None, 0] - a[..., 0]))
    return (cross >= -tol).all(axis=2)


def test_walk_finds_the_triangle_holding_each_point():
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(0, 50, (400, 2)), rng.normal(0, 1, 400)])
    queries = np.concatenate([rng.uniform(-2, 52, (3000, 2)), pts[:20, :2]])     # and on vertices
    t = GroundTin(pts)
    found = t.locate(queries)
    holders = contains(pts[:, :2][t.simplices], queries)
    inside = holders.any(axis=1)
    assert inside.sum() > 2000 and (~inside).sum() > 50
    assert holders[np.flatnonzero(inside), found[inside]].all()
    assert (found[~inside] < 0).all()
    far_start = np.full(300, len(t.simplices) - 1)                 # long walks from one triangle
    np.testing.assert_array_equal(t.locate(queries[:300], start=far_start), found[:300])
    assert triangle_set(t.simplices) == triangle_set(Delaunay(pts[:, :2]).simplices)


def brute_force_distance(p, tri, n=200):
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    keep = u + v <= 1
    samples = tri[0] + u[keep][:, None] * (tri[1] - tri[0]) + v[keep][:, None] * (tri[2] - tri[0])
    return np.linalg.norm(samples - p, axis=1).min()


def test_point_triangle_distance_matches_dense_sampling():
    rng = np.random.default_rng(2)
    tris = rng.uniform(0, 3, (40, 3, 3))
    pts = rng.uniform(-2, 5, (40, 3))
    got = point_triangle_distance(pts, tris)
    expected = np.array([brute_force_distance(p, t) for p, t in zip(pts, tris)])
    np.testing.assert_allclose(got, expected, atol=0.03)
    assert (got <= expected + 1e-9).all()


def test_distances_to_a_tilted_plane():
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 20, (200, 2))
    plane = np.column_stack([xy, 0.5 * xy[:, 0]])
    t = GroundTin(plane)
    q = np.column_stack([rng.uniform(5, 15, (50, 2)), np.zeros(50)])
    q[:, 2] = 0.5 * q[:, 0] + 2.0
    perpendicular = 2.0 / np.sqrt(1.25)
    distance, facet = t.measure(q)
    np.testing.assert_allclose(distance, perpendicular, rtol=1e-9)
    np.testing.assert_array_equal(facet, t.locate(q[:, :2]))
    # nearest facet among the facet under the point and its edge neighbours: at least the
    # plane distance, at most the vertical distance (the facet under the point holds the
    # point straight below), equal to the plane distance where the foot lies on a candidate
    nearest = t.distance_m(q, nearest_facet=True)
    assert (nearest >= perpendicular - 1e-9).all() and (nearest <= 2.0 + 1e-9).all()
    assert np.isclose(nearest, perpendicular, rtol=1e-9).mean() > 0.5
    assert np.isinf(t.distance_m(np.array([[100.0, 100.0, 0.0]]))).all()


INSERT_CASES = {            # name: (old points, new points) inside BOX, drawn from a seed
    "random": (200, 150),
    "one_point": (200, 1),
    "many_into_few": (3, 300),
    "clustered": (200, 60),
}


@pytest.mark.parametrize("name", sorted(INSERT_CASES))
@pytest.mark.parametrize("seed", [0, 1])
def test_insert_gives_qhulls_triangulation(name, seed):
    rng = np.random.default_rng(seed)
    n_old, n_new = INSERT_CASES[name]
    old_xy = np.concatenate([BOX, rng.uniform(0, 100, (n_old, 2))])
    new_xy = rng.uniform(40, 45, (n_new, 2)) if name == "clustered" else rng.uniform(0, 100, (n_new, 2))
    t = GroundTin(with_z(old_xy, rng))
    grown, changed = t.insert(with_z(new_xy, rng), t.locate(new_xy))
    assert grown.rebuilds == 0 and changed.shape == (len(t.simplices),)
    assert triangle_set(grown.simplices) == triangle_set(Delaunay(np.concatenate([old_xy, new_xy])).simplices)
    assert_valid_triangulation(grown)
    # triangles that did not change keep their id; the changed ones are gone
    np.testing.assert_array_equal(grown.simplices[:len(changed)][~changed], t.simplices[~changed])
    assert not triangle_set(t.simplices[changed]) & triangle_set(grown.simplices)
    np.testing.assert_array_equal(grown.xyz_m[:len(t.xyz_m)], t.xyz_m)


def test_batches_of_insertions_match_one_triangulation():
    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 100, (600, 2))
    t = GroundTin(with_z(np.concatenate([BOX, xy[:50]])))
    for lo, hi in [(50, 51), (51, 250), (250, 600)]:
        t, _ = t.insert(with_z(xy[lo:hi]), t.locate(xy[lo:hi]))
    assert triangle_set(t.simplices) == triangle_set(Delaunay(np.concatenate([BOX, xy])).simplices)


def test_insert_on_a_lattice_resolves_cocircular_ties():
    """Points on a 1 m lattice: every unit square is co-circular; the result is a Delaunay
    triangulation (not unique here) with consistent neighbours, without a full rebuild."""
    g = np.arange(20.0)
    xx, yy = np.meshgrid(g, g)
    lattice = np.column_stack([xx.ravel(), yy.ravel()])
    rng = np.random.default_rng(5)
    edge = (lattice == 0).any(axis=1) | (lattice == 19).any(axis=1)
    first = edge | (rng.random(len(lattice)) < 0.3)
    t = GroundTin(with_z(lattice[first]))
    grown, changed = t.insert(with_z(lattice[~first]), t.locate(lattice[~first]))
    assert grown.rebuilds == 0 and changed.any()
    assert len(grown.simplices) == 2 * 19 * 19
    assert_valid_triangulation(grown)


def test_insert_nothing_is_the_same_tin():
    rng = np.random.default_rng(6)
    t = GroundTin(with_z(np.concatenate([BOX, rng.uniform(0, 100, (30, 2))])))
    same, changed = t.insert(np.zeros((0, 3)), np.zeros(0, dtype=np.int64))
    np.testing.assert_array_equal(same.simplices, t.simplices)
    assert not changed.any()


@pytest.mark.parametrize("max_growth, rebuilds", [(0, 1), (4, 0)])
def test_strict_conflicts_on_a_lattice_grow_the_cavity_or_fall_back(monkeypatch, max_growth, rebuilds):
    """With strict conflicts (ties left out) the lattice leaves cavity walls that DT(S) does
    not keep: growing the cavity across them fixes that; with no growth allowed `insert`
    re-triangulates everything, says so, and marks every old triangle changed."""
    from gfjax.masf import insertion
    monkeypatch.setattr(insertion, "MAX_GROWTH", max_growth)
    monkeypatch.setattr(insertion, "TIE_TOL", 0.0)
    g = np.arange(12.0)
    xx, yy = np.meshgrid(g, g)
    lattice = np.column_stack([xx.ravel(), yy.ravel()])
    first = (lattice == 0).any(axis=1) | (lattice == 11).any(axis=1) | (np.random.default_rng(5).random(len(lattice)) < 0.3)
    t = GroundTin(with_z(lattice[first]))
    grown, changed = t.insert(with_z(lattice[~first]), t.locate(lattice[~first]))
    assert grown.rebuilds == rebuilds and changed.all() == (rebuilds == 1)
    assert_valid_triangulation(grown)
