"""gfjax.dtm.build: cell means, TIN fill with a maximum edge, snapped grid, units, bad input."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import scipy.spatial
from conftest import shared_file
from scipy.interpolate import LinearNDInterpolator

import gfjax.dtm
import gfjax.io.las
from gfjax.dtm.build import _rasterize_tin, snapped_grid
from gfjax.errors import InputError
from gfjax.io.cloud import Cloud

X0, Y0 = 512_345.678, 5_403_210.987          # UTM-sized coordinates
A, B, C = 0.31, -0.17, 250.0                   # plane z = A (x - X0) + B (y - Y0) + C


def plane(x, y):
    return A * (x - X0) + B * (y - Y0) + C


def _plane_cloud(n=1500, size_m=60.0, seed=0, hole=None, path=None):
    """Irregular samples of the plane; `hole=(cx, cy, half)` leaves a square without points."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, size_m, (n, 2))
    if hole is not None:
        cx, cy, half = hole
        xy = xy[(np.abs(xy[:, 0] - cx) > half) | (np.abs(xy[:, 1] - cy) > half)]
    xy += np.array([X0, Y0])
    cloud = Cloud.from_xyz(np.c_[xy, plane(xy[:, 0], xy[:, 1])], scale=1e-6)
    return cloud if path is None else dataclasses.replace(cloud, path=Path(path))


def _centres(dtm):
    """x, y of every cell centre, `(h, w)` each, from the affine transform."""
    h, w = dtm.shape
    t = dtm.transform
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    return t.c + cols * t.a + rows * t.b, t.f + cols * t.d + rows * t.e


def _cells_of(dtm, xy):
    """(row, col) of the cell holding each point: cell x in [c0, c0 + cell), y in [r0, r0 + cell)
    (docs/ARCHITECTURE.md: `row = h - 1 - floor(y / cell)`), so a point on a cell boundary
    belongs to the cell east / north of it."""
    t = dtm.transform
    return (int(round(t.f / dtm.cell)) - 1 - np.floor(xy[:, 1] / dtm.cell).astype(int),
            np.floor(xy[:, 0] / dtm.cell).astype(int) - int(round(t.c / dtm.cell)))


# --- the TIN rasteriser against scipy ----------------------------------------------------
TIN_CASES = [  # name, vertices (col, row, z), shape, max_edge_px
    ("random", np.c_[np.random.default_rng(1).uniform(0, 40, (200, 2)),
                     np.random.default_rng(2).normal(size=200)], (41, 43), np.inf),
    ("max_edge", np.c_[np.random.default_rng(3).uniform(0, 60, (120, 2)),
                       np.random.default_rng(4).normal(size=120)], (64, 60), 9.0),
    ("beyond_raster", np.c_[np.random.default_rng(5).uniform(-10, 30, (80, 2)),
                            np.random.default_rng(6).normal(size=80)], (16, 24), np.inf),
]


@pytest.mark.parametrize("name,vertices,shape,max_edge_px", TIN_CASES, ids=[c[0] for c in TIN_CASES])
def test_rasterize_tin_matches_scipy(name, vertices, shape, max_edge_px):
    h, w = shape
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    centres = np.c_[cols.ravel(), rows.ravel()]
    tri = scipy.spatial.Delaunay(vertices[:, :2])
    corners = vertices[tri.simplices, :2]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    simplex = tri.find_simplex(centres)
    usable = (simplex >= 0) & (longest[simplex] <= max_edge_px)
    expected = np.where(usable, LinearNDInterpolator(tri, vertices[:, 2])(centres), np.nan)
    got = _rasterize_tin(vertices, shape, max_edge_px)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expected.reshape(shape)))
    np.testing.assert_allclose(got, expected.reshape(shape), rtol=0, atol=1e-12)
    assert np.any(~np.isnan(got))
    np.testing.assert_array_equal(_rasterize_tin(vertices, shape, max_edge_px, chunk=5), got)


@pytest.mark.parametrize("vertices", [np.zeros((0, 3)), np.array([[1.0, 1.0, 5.0], [3.0, 2.0, 6.0]]),
                                      np.array([[0.5, 1.0, 1.0], [2.5, 1.0, 2.0], [7.5, 1.0, 3.0]])],
                         ids=["none", "two", "collinear"])
def test_rasterize_tin_without_triangles(vertices):
    assert np.all(np.isnan(_rasterize_tin(vertices, (4, 9), np.inf)))


# --- build -------------------------------------------------------------------------------
def test_plane_is_reproduced():
    cloud = _plane_cloud()
    dtm = gfjax.dtm.build(cloud, np.ones(cloud.n_points, bool), cell_m=1.0, max_edge_m=100.0)
    xyz = cloud.xyz
    rows, cols = _cells_of(dtm, xyz)
    assert dtm.count.sum() == cloud.n_points
    # occupied cells: the mean z of points on a plane = the plane at their centroid
    keys = rows * dtm.shape[1] + cols
    for key in np.unique(keys)[:200]:
        sel = keys == key
        r, c = divmod(int(key), dtm.shape[1])
        assert dtm.count[r, c] == sel.sum()
        cx, cy = xyz[sel, 0].mean(), xyz[sel, 1].mean()
        assert dtm.z[r, c] == pytest.approx(plane(cx, cy), abs=1e-5)
    # empty cells inside the hull of the cell centroids: the plane at the cell centre
    x, y = _centres(dtm)
    filled = (dtm.count == 0) & dtm.valid
    assert filled.sum() > 0.2 * dtm.z.size
    np.testing.assert_allclose(dtm.z[filled], plane(x[filled], y[filled]), rtol=0, atol=1e-5)
    # nodata only outside that hull (a thin rim along the tile border)
    nodata = ~dtm.valid
    assert 0 < nodata.sum() < 0.15 * dtm.z.size
    assert np.all(dtm.z[nodata] == gfjax.dtm.NODATA)
    centroids = np.array([[xyz[keys == k, 0].mean(), xyz[keys == k, 1].mean()] for k in np.unique(keys)])
    hull = scipy.spatial.Delaunay(centroids)
    assert np.all(hull.find_simplex(np.c_[x[nodata], y[nodata]]) < 0)


def test_max_edge_leaves_big_gap_as_nodata():
    cloud = _plane_cloud(n=3000, size_m=80.0, seed=1, hole=(40.0, 40.0, 15.0))
    ground = np.ones(cloud.n_points, bool)
    short = gfjax.dtm.build(cloud, ground, cell_m=2.0, max_edge_m=10.0)
    long = gfjax.dtm.build(cloud, ground, cell_m=2.0, max_edge_m=100.0)
    x, y = _centres(short)
    centre = (np.abs(x - X0 - 40.0) < 10.0) & (np.abs(y - Y0 - 40.0) < 10.0)
    assert centre.sum() == 100
    assert np.all(~short.valid[centre])
    assert np.all(long.valid[centre])
    np.testing.assert_allclose(long.z[centre], plane(x[centre], y[centre]), atol=1e-5)
    outside_hole = (np.abs(x - X0 - 40.0) > 20.0) | (np.abs(y - Y0 - 40.0) > 20.0)
    interior = (x - X0 > 5) & (x - X0 < 75) & (y - Y0 > 5) & (y - Y0 < 75)
    assert np.all(short.valid[outside_hole & interior])


@pytest.mark.parametrize("cell_m", [1.0, 2.5])
def test_grid_is_snapped_and_covers_every_point(cell_m):
    rng = np.random.default_rng(7)
    xyz = np.c_[rng.uniform(1000.3, 1040.7, 300), rng.uniform(2000.1, 2031.9, 300), rng.normal(size=300)]
    xyz[0, :2] = [1050.0, 2035.0]                              # exactly on a cell boundary
    cloud = Cloud.from_xyz(xyz, scale=1e-3)
    ground = np.zeros(cloud.n_points, bool)
    ground[::2] = True
    dtm = gfjax.dtm.build(cloud, ground, cell_m=cell_m)
    t = dtm.transform
    assert (t.a, t.b, t.d, t.e) == (cell_m, 0.0, 0.0, -cell_m)
    assert t.c / cell_m == np.floor(t.c / cell_m) and t.f / cell_m == np.floor(t.f / cell_m)
    assert t.c <= 1000.3 and t.c + cell_m > 1000.3
    rows, cols = _cells_of(dtm, cloud.xyz)                     # every point, ground or not
    assert rows.min() == 0 and cols.min() == 0
    assert rows.max() == dtm.shape[0] - 1 and cols.max() == dtm.shape[1] - 1
    assert (rows[0], cols[0]) == (0, dtm.shape[1] - 1)         # (1050, 2035): north-east cell
    expected = np.zeros(dtm.shape, int)
    np.add.at(expected, (rows[ground], cols[ground]), 1)
    np.testing.assert_array_equal(dtm.count, expected)


def test_noise_points_do_not_stretch_the_grid():
    xyz = np.array([[0.5, 0.5, 1.0], [3.5, 2.5, 2.0], [9000.0, -9000.0, 900.0]])
    cloud = Cloud.from_xyz(xyz, classification=np.array([2, 1, 7], np.uint8))
    dtm = gfjax.dtm.build(cloud, cloud.classification == 2)
    assert dtm.shape == (3, 4)                                  # the noise point is ignored


def test_snapped_grid_counts():
    xy = np.array([[0.0, 0.0], [9.999, 4.0], [10.0, -0.5]])
    assert snapped_grid(xy, 2.0) == (0, 3, 4, 6)   # cols 0..5, rows of y in [-2, 6): 4


def test_single_point_and_one_row():
    one = Cloud.from_xyz(np.array([[10.2, 20.7, 3.5]]))
    dtm = gfjax.dtm.build(one, np.ones(1, bool))
    assert dtm.shape == (1, 1) and dtm.z[0, 0] == pytest.approx(3.5)
    row = Cloud.from_xyz(np.c_[np.arange(10.0) * 3 + 0.5, np.full(10, 0.5), np.arange(10.0)])
    dtm = gfjax.dtm.build(row, np.ones(10, bool), cell_m=1.0)
    assert dtm.shape == (1, 28)
    assert dtm.valid.sum() == 10                               # collinear: no triangle, no fill


@pytest.mark.data
def test_feet_cell_is_converted():
    path = shared_file("pdal_autzen/autzen_trim.laz")
    cloud = gfjax.io.las.read(path)                       # feet from the file's CRS
    assert (cloud.horizontal_unit_m, cloud.vertical_unit_m) == (0.3048, 0.3048)
    ground = cloud.classification == 2
    dtm = gfjax.dtm.build(cloud, ground, cell_m=1.0, max_edge_m=30.0)
    assert dtm.cell == pytest.approx(3.2808399, rel=1e-7)
    assert dtm.transform.a == dtm.cell and dtm.transform.e == -dtm.cell
    xyz = cloud.xyz                                            # feet: never converted
    assert dtm.transform.c <= xyz[:, 0].min() < dtm.transform.c + dtm.cell
    assert np.isclose(dtm.transform.c / dtm.cell, round(dtm.transform.c / dtm.cell), rtol=0, atol=1e-6)
    extent_cells = (xyz[:, 0].max() - xyz[:, 0].min()) / dtm.cell
    assert extent_cells <= dtm.shape[1] <= extent_cells + 2
    assert dtm.crs is not None and dtm.crs.linear_units_factor[1] == pytest.approx(0.3048)
    occupied = dtm.count > 0
    z_ground = xyz[ground, 2]
    assert z_ground.min() <= dtm.z[occupied].min() and dtm.z[occupied].max() <= z_ground.max()


def test_no_ground_names_the_file():
    cloud = _plane_cloud(n=50, path="tile_without_ground.laz")
    with pytest.raises(InputError, match="tile_without_ground.laz.*no ground"):
        gfjax.dtm.build(cloud, np.zeros(cloud.n_points, bool))


@pytest.mark.parametrize("kwargs,match", [(dict(cell_m=0.0), "cell_m"), (dict(cell_m=float("nan")), "cell_m"),
                                          (dict(cell_m=float("inf")), "cell_m"), (dict(cell_m="1"), "cell_m"),
                                          (dict(max_edge_m=-1.0), "max_edge_m")])
def test_bad_options(kwargs, match, unchecked):
    cloud = _plane_cloud(n=50, path="t.laz")
    with pytest.raises(InputError, match=f"t.laz.*{match}"):
        gfjax.dtm.build(cloud, np.ones(cloud.n_points, bool), **kwargs)


def test_bad_ground_array():
    cloud = _plane_cloud(n=50, path="t.laz")
    with pytest.raises(InputError, match="ground"):
        gfjax.dtm.build(cloud, np.ones(cloud.n_points - 1, bool))
    with pytest.raises(InputError, match="ground"):
        gfjax.dtm.build(cloud, np.full(cloud.n_points, 2, np.uint8))


def test_context_points_give_the_border_cells_their_whole_survey_values():
    """Two halves of one cloud: each half's DTM, built with the other half as context, equals
    the whole cloud's DTM on its own grid, cell for cell (border cells and triangles included);
    without context the cells along the cut differ."""
    whole = _plane_cloud(n=4000, size_m=80.0, seed=5)
    xyz = whole.xyz
    ground = np.ones(whole.n_points, bool)
    full = gfjax.dtm.build(whole, ground)
    west = xyz[:, 0] < np.median(xyz[:, 0])
    for half in (west, ~west):
        part = Cloud.from_xyz(xyz[half], scale=1e-6)
        alone = gfjax.dtm.build(part, np.ones(int(half.sum()), bool))
        framed = gfjax.dtm.build(part, np.ones(int(half.sum()), bool), context_xyz=xyz[~half])
        assert framed.shape == alone.shape and framed.origin == alone.origin
        col = round((framed.origin[0] - full.origin[0]) / full.cell)
        row = round((full.origin[1] - framed.origin[1]) / full.cell)
        h, w = framed.shape
        np.testing.assert_allclose(framed.z, full.z[row:row + h, col:col + w], rtol=0, atol=1e-9)  # sum order
        np.testing.assert_array_equal(framed.count, full.count[row:row + h, col:col + w])
        assert np.any(alone.z != framed.z)
