"""MASF host geometry: 3D Delaunay faces, the TIN point location walk, point-to-TIN distances."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from gfjax.masf import tin
from gfjax.masf.tin import GroundTin, _point_triangle_distance


def test_faces_are_the_unique_triangles_with_their_opposite_vertices():
    rng = np.random.default_rng(0)
    xyz = rng.uniform(0, 10, (60, 3))
    faces, opposite = tin.delaunay_faces(xyz)
    tets = Delaunay(xyz).simplices
    expected = {}
    for tet in tets:
        for j in range(4):
            key = tuple(sorted(np.delete(tet, j)))
            expected.setdefault(key, []).append(tet[j])
    got = {tuple(sorted(f)): sorted(o[o >= 0].tolist()) for f, o in zip(faces, opposite)}
    assert got == {k: sorted(v) for k, v in expected.items()}


@pytest.mark.parametrize("xyz", [np.zeros((3, 3)), np.eye(3), np.column_stack([np.arange(8.0)] * 3),
                                 np.column_stack([np.arange(9.0) % 3, np.arange(9.0) // 3, np.zeros(9)])],
                         ids=["three", "eye", "collinear", "coplanar"])
def test_degenerate_input_returns_none(xyz):
    assert tin.delaunay_faces(xyz) is None


def test_walk_locates_like_scipy():
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(0, 50, (400, 2)), rng.normal(0, 1, 400)])
    queries = rng.uniform(-2, 52, (3000, 2))
    t = GroundTin(pts)
    found = t.locate(queries)
    expected = t._tri.find_simplex(queries)
    inside = expected >= 0
    np.testing.assert_array_equal(found[inside], expected[inside])
    assert (found[~inside] < 0).all()


def brute_force_distance(p, tri, n=200):
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    keep = u + v <= 1
    samples = tri[0] + u[keep][:, None] * (tri[1] - tri[0]) + v[keep][:, None] * (tri[2] - tri[0])
    return np.linalg.norm(samples - p, axis=1).min()


def test_point_triangle_distance_matches_dense_sampling():
    rng = np.random.default_rng(2)
    tris = rng.uniform(0, 3, (40, 3, 3))
    pts = rng.uniform(-2, 5, (40, 3))
    got = _point_triangle_distance(pts, tris)
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
    np.testing.assert_allclose(t.distance_m(q), perpendicular, rtol=1e-9)
    # nearest facet among the facet under the point and its edge neighbours: at least the
    # plane distance, at most the vertical distance (the facet under the point holds the
    # point straight below), equal to the plane distance where the foot lies on a candidate
    nearest = t.distance_m(q, nearest_facet=True)
    assert (nearest >= perpendicular - 1e-9).all() and (nearest <= 2.0 + 1e-9).all()
    assert np.isclose(nearest, perpendicular, rtol=1e-9).mean() > 0.5
    assert np.isinf(t.distance_m(np.array([[100.0, 100.0, 0.0]]))).all()
