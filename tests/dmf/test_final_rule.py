"""DMF step 7 readings (Wu et al. 2025, Sec. 2.6): the height threshold in multiples of W, the
lowest-point support elevation and the combined rule, on the shrub scene (flat ground under a
patch of understory 0.45 m high; W = 1 m) whose answer is known; support elevations carried
from where they were measured to the cell centres, on planes and a steep ramp."""
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
    """Default: the height rule at 0.15 W = 0.15 m; the understory stands 0.45 m high."""
    flag, _, d = shrub
    cloud, _ = scenes.shrub_scene()
    result = dmf.filter(cloud)
    assert float(dmf.Params().threshold_m(d.cell_m)) == pytest.approx(0.15)
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


def test_column_lowest_matches_a_loop():
    from gfjax.dmf import voxels
    rng = np.random.default_rng(7)
    xyz = np.column_stack([rng.uniform(0, 9, 300), rng.uniform(0, 7, 300), rng.uniform(0, 5, 300)])
    vox = voxels.bin_voxels(xyz, 2.0)
    lowest = extract.column_lowest(xyz, vox)
    for node, cell in enumerate(vox.cell):
        column = xyz[vox.point_cell == cell]
        np.testing.assert_array_equal(lowest[node], column[np.argmin(column[:, 2])])


def test_lowest_support_elevation_is_the_lower_envelope(shrub):
    """A centroid sits 0.11 m above the ground where its cell holds understory, so at 0.38 m
    the centroid surface takes some understory as ground and the lowest-point surface none."""
    flag, local, d = shrub
    low_nodes, low = _ground(shrub, dmf.Config(support_elevation="lowest"), dmf.Params(height_threshold_m=0.38,
                                                                                         height_threshold_w=0.0))
    own = low_nodes.from_ndng
    flat = dmf.Config(support_elevation="lowest", support_position="centre")
    flat_nodes, _ = _ground(shrub, flat, dmf.Params())
    np.testing.assert_array_equal(flat_nodes.z_surface[own], extract.column_lowest(local, d.voxels)[own, 2])
    np.testing.assert_allclose(low_nodes.z_surface[own], flat_nodes.z_surface[own], atol=0.05)   # flat: carried little
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


def _plane_nodes(slope_x: float, slope_y: float, cell_m: float = 2.0, seed: int = 3):
    """Voxels of points on the plane `z = 10 + slope_x x + slope_y y` over 40 m x 30 m (4 points
    per m^2, jittered), their plane, and each cell centre's x, y."""
    from gfjax.dmf import voxels
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 1, (4800, 2)) * [40.0, 30.0]
    plane = lambda x, y: 10.0 + slope_x * x + slope_y * y                       # noqa: E731
    vox = voxels.bin_voxels(np.column_stack([xy, plane(xy[:, 0], xy[:, 1])]), cell_m)
    h, w = vox.shape
    centre = np.column_stack([(vox.cell % w + 0.5) * cell_m, (h - 1 - vox.cell // w + 0.5) * cell_m])
    return vox, plane, centre


@pytest.mark.parametrize("slope", [(0.0, 0.0), (0.7, 0.0), (0.6, -0.8)])
def test_carry_to_centres_is_exact_on_a_plane(slope):
    """The lowest voxel of a steep cell holds its downhill part, so the centroid lies below the
    plane at the centre; carried along the plane of its neighbours, it lands on it."""
    vox, plane, centre = _plane_nodes(*slope)
    known = np.ones(len(vox.cell), bool)
    at_centre = plane(centre[:, 0], centre[:, 1])
    carried = extract.carry_to_centres(vox.centroid[:, 2], vox.centroid[:, :2], vox, known)
    h, w = vox.shape
    row, col = vox.cell // w, vox.cell % w
    inner = (row > 0) & (row < h - 1) & (col > 0) & (col < w - 1)
    np.testing.assert_allclose(carried[inner], at_centre[inner], atol=1e-6)
    if slope != (0.0, 0.0):
        assert np.mean(vox.centroid[inner, 2] - at_centre[inner]) < -0.15      # the paper's placement
        assert np.abs(carried - at_centre).mean() < 0.1 * np.abs(vox.centroid[:, 2] - at_centre).mean()


def test_carry_to_centres_in_bands_of_rows_is_the_same(monkeypatch):
    """The window sums are taken a band of rows at a time (memory); bands of 2 rows give what
    one band gives, to the last bit."""
    vox, _, _ = _plane_nodes(0.6, -0.8)
    known = np.random.default_rng(2).uniform(size=len(vox.cell)) < 0.7
    whole = extract.carry_to_centres(vox.centroid[:, 2], vox.centroid[:, :2], vox, known)
    monkeypatch.setattr(extract, "_BAND_ROWS", 2)
    np.testing.assert_array_equal(extract.carry_to_centres(vox.centroid[:, 2], vox.centroid[:, :2], vox, known), whole)


def test_carry_to_centres_stays_within_its_neighbours():
    """A node left on an object tilts its neighbours' fits; no carried elevation leaves the
    range of its 3x3 known nodes, nodes not known come back as they are, and a lone node keeps
    its elevation."""
    vox, _, _ = _plane_nodes(0.3, 0.1)
    rng = np.random.default_rng(5)
    z = vox.centroid[:, 2] + np.where(rng.uniform(size=len(vox.cell)) < 0.1, 8.0, 0.0)
    known = rng.uniform(size=len(vox.cell)) < 0.8
    carried = extract.carry_to_centres(z, vox.centroid[:, :2], vox, known)
    np.testing.assert_array_equal(carried[~known], z[~known])
    h, w = vox.shape
    grid = np.full((h + 2, w + 2), np.nan)
    grid[vox.cell[known] // w + 1, vox.cell[known] % w + 1] = z[known]
    for node in np.flatnonzero(known):
        r, c = vox.cell[node] // w + 1, vox.cell[node] % w + 1
        around = grid[r - 1:r + 2, c - 1:c + 2]
        assert np.nanmin(around) - 1e-9 <= carried[node] <= np.nanmax(around) + 1e-9
    lone = np.zeros(len(vox.cell), bool)
    lone[0] = True
    np.testing.assert_array_equal(extract.carry_to_centres(z, vox.centroid[:, :2], vox, lone), z)


def test_carried_support_keeps_a_steep_ramp():
    """A plane rising 1 m per metre (W = 1 m): at the cell centres the support surface drops
    half the ground below the threshold; carried from the centroids it keeps most of it."""
    cloud, ground = scenes.ramp_scene(slope=1.0)
    kept = {position: dmf.filter(cloud, config=dmf.Config(support_position=position)).ground[ground].mean()
            for position in ("centre", "centroid")}
    assert kept["centre"] < 0.6 and kept["centroid"] > 0.85


def test_bad_readings_are_rejected():
    with pytest.raises(ValueError, match="support_elevation"):
        dmf.Config(support_elevation="median")
    with pytest.raises(ValueError, match="support_position"):
        dmf.Config(support_position="middle")
    with pytest.raises(ValueError, match="final_rule"):
        dmf.Config(final_rule="either")
