"""MASF host geometry: the 3D Delaunay faces of the alpha shape."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from gfjax.masf import tin


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
