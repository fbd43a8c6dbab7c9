"""`gfjax.dmf.filter` end to end on synthetic scenes with a known answer, and its input checks."""
from __future__ import annotations

import dataclasses

import dmf_scenes as scenes
import numpy as np
import pytest

import gfjax
from gfjax import dmf
from gfjax.errors import InputError


@pytest.fixture(scope="session")
def box():
    cloud, ground, roof = scenes.box_scene()
    return cloud, ground, roof, dmf.filter(cloud)


@pytest.fixture(scope="session")
def ramp():
    cloud, ground = scenes.ramp_scene()
    return cloud, ground, dmf.filter(cloud)


def test_result_shapes_and_types(box):
    cloud, _, _, result = box
    assert isinstance(result, gfjax.Result)
    assert result.ground.shape == (cloud.n_points,) and result.ground.dtype == bool
    assert result.instance_id.shape == (cloud.n_points,) and result.instance_id.dtype == np.uint32
    d = result.diagnostics
    assert isinstance(d, dmf.Diagnostics) and d.converged
    assert d.cell_m == 1.0 and d.ngnem.shape == (48, 48)
    assert d.support.xyz.shape == (len(d.nd_ce), 3)


def test_box_building_is_detected_and_survives_the_correction(box):
    """Steps 4-6: the building's cells are in R_HC's holes -> NGNEM_BI -> NGNEM_RC."""
    _, _, _, result = box
    d = result.diagnostics
    x0, x1, y0, y1 = (int(v) for v in scenes.BOX)
    h = d.ngnem.shape[0]
    inner = np.zeros(d.ngnem.shape, bool)
    inner[h - y1 + 1:h - y0 - 1, x0 + 1:x1 - 1] = True            # the roof, one cell in from its edge
    assert d.ngnem_bi[inner].all() and d.ngnem_rc0[inner].all() and d.ngnem_rc[inner].all()
    assert d.ngnem_rc.sum() <= (x1 - x0 + 2) * (y1 - y0 + 2)         # nothing far outside it
    assert not d.rhc[inner].any()                                   # R_HC is the outline, not the roof
    assert d.instances.max() == 1


def test_box_roof_points_are_nonground_with_one_instance(box):
    _, ground, roof, result = box
    assert not result.ground[roof].any()
    assert np.all(result.instance_id[~roof] == 0)
    ids = np.unique(result.instance_id[roof])
    assert set(ids) <= {0, 1} and (result.instance_id[roof] == 1).mean() > 0.95
    assert result.ground[ground].mean() > 0.7                       # the M-nearest rule omits some ground


def test_ramp_marks_nothing(ramp):
    _, ground, result = ramp
    d = result.diagnostics
    assert not d.rhc.any() and not d.ngnem_bi.any() and not d.ngnem_rc.any()
    assert not result.instance_id.any()
    assert result.ground.mean() > 0.7


def test_basal_layer_keeps_flat_ground(ramp):
    d = ramp[2].diagnostics
    assert d.basal_iterations < 20
    assert np.all(d.basal_z <= d.nd_ce[:, 2] + 1e-4)
    assert d.in_ndng.mean() > 0.5


def test_height_rule_on_the_box(box):
    cloud, ground, roof, _ = box
    result = dmf.filter(cloud, config=dmf.Config(final_rule="height"),
                         params=dmf.Params(height_threshold_m=0.5, height_threshold_w=0.0))
    assert not result.ground[roof].any()
    assert result.ground[ground].mean() > 0.97


def test_point_order_does_not_matter(box):
    cloud, _, _, result = box
    perm = np.random.default_rng(0).permutation(cloud.n_points)
    shuffled = gfjax.Cloud.from_xyz(cloud.xyz[perm])
    again = dmf.filter(shuffled)
    np.testing.assert_array_equal(again.ground, result.ground[perm])
    np.testing.assert_array_equal(again.instance_id, result.instance_id[perm])


def test_ignored_points_are_never_ground():
    cloud, ground, _ = scenes.box_scene()
    cls = np.where(ground, 2, 1)
    cls[::7] = 7
    noisy = gfjax.Cloud.from_xyz(cloud.xyz, classification=cls)
    result = dmf.filter(noisy)
    assert not result.ground[::7].any() and not result.instance_id[::7].any()


def test_empty_and_tiny_clouds():
    empty = gfjax.Cloud.from_xyz(np.zeros((0, 3)))
    assert dmf.filter(empty).ground.shape == (0,)


def test_bad_input(unchecked):
    cloud, _, _ = scenes.box_scene()
    with pytest.raises(InputError, match="config"):
        dmf.filter(cloud, config={"v0": 2})
    with pytest.raises(InputError, match="returns"):
        dmf.filter(cloud, returns="first")
    with pytest.raises(InputError, match="Cloud"):
        dmf.filter(np.zeros((3, 3)))
    with pytest.raises(InputError, match="height_threshold_w must be finite"):
        dmf.filter(cloud, params=dmf.Params(height_threshold_w=float("nan")))
    with pytest.raises(ValueError, match="basal_stop"):
        dmf.Config(basal_stop="sometimes")
    with pytest.raises(ValueError, match="v0"):
        dmf.Config(v0=0)
    with pytest.raises(ValueError, match="close_max_px"):
        dmf.Config(close_max_px=4)


def test_config_is_hashable_and_presets_are_valid():
    for overrides in dmf.PRESETS.values():
        config = dataclasses.replace(dmf.Config(), **overrides)
        hash(config)
    assert dmf.Config().basal_neighbours == 49


def test_tiled_raster_stages_equal_one_tile(box):
    """Multi-tile path: 2 x 2 NGNEM tiles (core 24 m, buffer 14 m, padded to 48 x 48) run as one
    vmapped batch, stitched by core; every window holds the whole building: equals one tile."""
    cloud, _, _, single = box
    tiled = dmf.filter(cloud, tiling=gfjax.Tiling(tile_size_m=24.0, buffer_m=14.0))
    for name in ("rhc", "ngnem_bi", "ngnem_rc", "instances"):
        np.testing.assert_array_equal(getattr(tiled.diagnostics, name), getattr(single.diagnostics, name), err_msg=name)
    np.testing.assert_array_equal(tiled.ground, single.ground)
    np.testing.assert_array_equal(tiled.instance_id, single.instance_id)


def test_paper_preset_on_the_box(box):
    """The SPEC's first reading (global stop, per-patch hole test, the M-nearest rule)."""
    cloud, ground, roof, _ = box
    config = dataclasses.replace(dmf.Config(), **dmf.PRESETS["paper"])
    result = dmf.filter(cloud, config=config)
    d = result.diagnostics
    assert d.m_points >= 1 and d.converged and d.instances.max() == 1
    assert not result.ground[roof].any()
    assert result.ground[ground].mean() > 0.7


@pytest.mark.parametrize("copies", [1, 3], ids=["square", "rectangle"])
def test_warm_prepares_every_program_filter_runs(monkeypatch, copies):
    """A cloud of a size never seen runs only programs `dmf.warm` prepares (canonical raster
    shapes, node and point capacities): after `gfjax warmup`, its first run compiles nothing.
    Three copies of the box scene side by side make a 48 x 144 m cloud, whose NGNEM is padded
    to 192 x 128 cells, not a square. The programs' keys are compared; nothing is compiled for
    `warm`."""
    from gfjax import aot

    ran, prepared = set(), set()
    monkeypatch.setattr(aot, "call", lambda fn, *args, tag=None, **static: (
        ran.add(aot.program_key(fn, args, static, tag)), fn(*args, **static))[1])
    monkeypatch.setattr(aot, "prefetch", lambda fn, *specs, tag=None, **static: None)
    cloud, _, _ = scenes.box_scene()
    keep = np.random.default_rng(0).random(cloud.n_points) < 0.83          # another point count
    xyz = np.vstack([cloud.xyz_m[keep] + [0.0, scenes.SIZE_M * i, 0.0] for i in range(copies)])
    result = dmf.filter(gfjax.Cloud.from_xyz(xyz))
    assert result.diagnostics.ngnem.shape == (48 * copies, 48)
    monkeypatch.setattr(aot, "prefetch", lambda fn, *specs, tag=None, **static: prepared.add(
        aot.program_key(fn, specs, static, tag)))
    assert dmf.warm() > 0
    assert ran and ran <= prepared, f"{len(ran - prepared)} of {len(ran)} programs not warmed"


def test_every_program_filter_prefetches_is_one_it_runs(monkeypatch):
    """The loads `filter` starts ahead on its worker (the raster stages, the basal loop, the
    height rule) name the programs its calls then run: none is loaded for nothing."""
    from gfjax import aot

    ran, prefetched = set(), set()
    monkeypatch.setattr(aot, "call", lambda fn, *args, tag=None, **static: (
        ran.add(aot.program_key(fn, args, static, tag)), fn(*args, **static))[1])
    monkeypatch.setattr(aot, "prefetch", lambda fn, *specs, tag=None, **static: prefetched.add(
        aot.program_key(fn, specs, static, tag)))
    cloud, _, _ = scenes.box_scene()
    dmf.filter(cloud)
    assert len(prefetched) == 4 and prefetched <= ran, f"{len(prefetched - ran)} of {len(prefetched)} not run"


def test_groups_far_apart_number_their_instances_on(box):
    """Two copies of the box scene 10 km apart are filtered group by group: each copy gets the
    labels it gets alone, and the second copy's object ids follow the first's."""
    cloud, _, _, alone = box
    xyz = cloud.xyz_m
    both = dmf.filter(gfjax.Cloud.from_xyz(np.vstack([xyz, xyz + [10_000.0, 10_000.0, 0.0]])))
    n = len(xyz)
    assert both.diagnostics is None
    np.testing.assert_array_equal(both.ground[:n], alone.ground)
    np.testing.assert_array_equal(both.ground[n:], alone.ground)
    first, second = both.instance_id[:n], both.instance_id[n:]
    np.testing.assert_array_equal(first, alone.instance_id)
    assert first.max() > 0
    np.testing.assert_array_equal(second, np.where(alone.instance_id > 0, alone.instance_id + first.max(), 0))
