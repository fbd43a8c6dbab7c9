"""Buffered tiles: each point labelled once, seamless merge, vmap == tile by tile, invariances."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gfjax.errors import InputError, SettingError
from gfjax.io import columns
from gfjax.io.cloud import Cloud, Frame
from gfjax.smrf import Config, Params, programs
from gfjax.smrf import filter as smrf_filter
from gfjax.tiling import batches, buckets, driver
from gfjax.tiling import tiles as tiling

ORIGIN = np.array([512_345.0, 5_403_210.0, 250.0])        # UTM-sized: float32 would lose cm


def dense_scene(seed=0, size_m=64, boxes=6):
    """Gently sloped ground with two points per 1 m cell (kept off the cell edges) and small
    4 x 4 m boxes 6 m tall, so that every cell holds a point and every hole is enclosed."""
    rng = np.random.default_rng(seed)
    cols, rows = np.meshgrid(np.arange(size_m), np.arange(size_m))
    centre = np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], axis=1)
    xy = np.concatenate([centre + rng.uniform(-0.35, 0.35, centre.shape) for _ in range(2)])
    z = 0.03 * xy[:, 0] + 0.02 * xy[:, 1] + rng.normal(0, 0.03, len(xy))
    building = np.zeros(len(xy), bool)
    for bx, by in rng.integers(3, size_m - 7, size=(boxes, 2)):
        building |= (xy[:, 0] >= bx) & (xy[:, 0] < bx + 4) & (xy[:, 1] >= by) & (xy[:, 1] < by + 4)
    z[building] += 6.0
    return np.column_stack([xy, z]) + ORIGIN, ~building


CONFIG = Config(window_m=3.0)
TILED = tiling.Tiling(tile_size_m=32.0, buffer_m=16.0)
WHOLE = tiling.Tiling(tile_size_m=500.0, buffer_m=16.0)


@pytest.fixture(scope="module")
def scene():
    return dense_scene()[0]


def test_every_point_in_exactly_one_core_and_in_its_window():
    rng = np.random.default_rng(1)
    xyz = rng.uniform(0, 1000, (20_000, 3)) + ORIGIN
    use = rng.random(len(xyz)) > 0.1
    tiles = tiling.split(xyz, tile_size_m=300.0, buffer_m=40.0, cell_m=1.0, use=use)
    count = np.zeros(len(xyz), int)
    for tile in tiles:
        np.add.at(count, tile.index[tile.core], 1)
        local = xyz[tile.index] - tile.origin_m
        assert np.all(local[:, :2] >= 0)
        assert np.all(local[:, :2] < np.array(tile.shape[::-1]) * 1.0)
        # float32 local xy stay in the float64 cell
        np.testing.assert_array_equal(np.floor(tile.local_xyz[:, :2]), np.floor(local[:, :2]))
        # the window holds every used point within the buffer of the core
        c0, r0, c1, r1 = tile.core_px
        rel = xyz - xyz[use].min(axis=0)
        near = use & (rel[:, 0] >= c0 - 40) & (rel[:, 0] < c1 + 40) & (rel[:, 1] >= r0 - 40) & (rel[:, 1] < r1 + 40)
        assert set(np.flatnonzero(near)) <= set(tile.index)
    np.testing.assert_array_equal(count, use.astype(int))
    merged = tiling.merge(len(xyz), tiles, [np.ones(t.n_points, bool) for t in tiles])
    np.testing.assert_array_equal(merged, use)


def test_a_window_of_few_points_shrinks_to_their_surroundings():
    """A core whose points fill little of its window rasterises their box grown by the buffer
    (a quarter of the window or less), and keeps every window point within the buffer."""
    rng = np.random.default_rng(2)
    patch = rng.uniform(0, 40, (2000, 3))
    patch[0] = 0.0                                                  # anchors the lattice at ORIGIN
    lone = np.array([[1000.5, 1000.5, 3.0]])
    xyz = np.vstack([patch, lone]) + ORIGIN
    tiles = tiling.split(xyz, tile_size_m=300.0, buffer_m=20.0, cell_m=1.0)
    assert {t.key: t.shape for t in tiles} == {(0, 0): (60, 60), (3, 3): (21, 21)}
    by_key = {t.key: t for t in tiles}
    assert by_key[(0, 0)].core_px == (0, 0, 60, 60) and by_key[(0, 0)].n_points == 2000
    assert by_key[(3, 3)].window_px == (980, 980) and list(by_key[(3, 3)].index) == [2000]
    merged = tiling.merge(len(xyz), tiles, [np.ones(t.n_points, bool) for t in tiles])
    assert merged.all()


def test_windows_of_a_filled_box_are_not_cut(scene, monkeypatch):
    cut = tiling.split(scene, tile_size_m=32.0, buffer_m=16.0, cell_m=1.0)
    monkeypatch.setattr(tiling, "CROP_SAVING", np.inf)
    whole = tiling.split(scene, tile_size_m=32.0, buffer_m=16.0, cell_m=1.0)
    assert [(t.shape, t.window_px, t.core_px) for t in cut] == [(t.shape, t.window_px, t.core_px) for t in whole]
    assert all(np.array_equal(a.index, b.index) for a, b in zip(cut, whole))


@pytest.mark.parametrize("size_m, tile_m", [(64, 500.0), (150, 60.0), (333, 100.0)])
def test_canonical_batches_use_only_canonical_shapes(size_m, tile_m):
    rng = np.random.default_rng(size_m)
    xyz = np.column_stack([rng.uniform(0, size_m, (3000, 2)), rng.normal(0, 1, 3000)]) + ORIGIN
    tiles = tiling.split(xyz, tile_size_m=tile_m, buffer_m=10.0, cell_m=1.0)
    sides = buckets.canonical_sides(tile_m, 10.0, 1.0)
    found = list(batches.batches(tiles, max_batch=3, sides=sides))
    assert sorted(t.key for b in found for t in b.tiles) == sorted(t.key for t in tiles)
    for batch in found:
        assert batch.shape[0] == batch.shape[1] and batch.shape[0] in sides
        assert len(batch.tiles) in (1, 3)                       # a full batch, or one tile
        assert batch.xyz.shape[1] in buckets.canonical_capacities()
        side = min(s for s in sides if s >= max(max(t.shape) for t in batch.tiles))
        assert batch.shape[0] == side                           # the smallest side that holds it


def test_batches_cover_every_tile_once(scene):
    tiles = tiling.split(scene, tile_size_m=32.0, buffer_m=16.0, cell_m=1.0)
    seen = [t.key for b in batches.batches(tiles, max_batch=4) for t in b.tiles]
    assert sorted(seen) == sorted(t.key for t in tiles) and len(tiles) == 4
    for batch in batches.batches(tiles, max_batch=4):
        np.testing.assert_array_equal(batch.valid.sum(axis=1), [t.n_points for t in batch.tiles])


def test_bad_options_raise():
    with pytest.raises(ValueError, match="tile_size_m"):
        tiling.split(np.zeros((3, 3)), tile_size_m=0.5, cell_m=1.0)
    with pytest.raises(ValueError, match="buffer_m"):
        tiling.split(np.zeros((3, 3)), buffer_m=-1.0)
    assert tiling.split(np.zeros((3, 3)), use=np.zeros(3, bool)) == []


@pytest.mark.parametrize("kwargs, key", [({"tile_size_m": 0.0}, "tile_size_m"), ({"tile_size_m": float("nan")}, "tile_size_m"),
                                         ({"buffer_m": -1.0}, "buffer_m"), ({"buffer_m": 1e6}, "buffer_m")])
def test_a_tiling_out_of_range_names_its_field(kwargs, key):
    with pytest.raises(SettingError, match=rf"^{key} must be") as err:
        tiling.Tiling(**kwargs)
    assert err.value.keys == (key,)


def test_a_tiling_is_an_option_of_the_run_not_of_the_method(scene, unchecked):
    """A core smaller than the method's cell, or something else than a Tiling, is refused by
    the filter naming the cloud; the tiling never enters the compiled programs' settings."""
    assert tiling.Tiling(tile_size_m=30.0, buffer_m=5.0).lattice(2.0) == tiling.Lattice(30.0, 5.0, 2.0)
    cloud = Cloud.from_xyz(scene)
    with pytest.raises(InputError, match=r"^<memory>: tile_size_m must be >= the cell \(2 m\), got 1.0$"):
        smrf_filter(cloud, config=Config(cell_m=2.0, window_m=6.0), tiling=tiling.Tiling(tile_size_m=1.0))
    with pytest.raises(InputError, match="^tiling must be a gfjax.Tiling, got dict$"):
        smrf_filter(cloud, tiling={"tile_size_m": 100.0})
    assert not any(f.name in ("tile_size_m", "buffer_m") for f in dataclasses.fields(Config))


@pytest.fixture(scope="module")
def whole(scene):
    return smrf_filter(Cloud.from_xyz(scene), config=CONFIG, tiling=WHOLE)


@pytest.fixture(scope="module")
def whole_labels(whole):
    return whole.ground


def test_smrf_whole_equals_tiled(scene, whole, whole_labels):
    """SMRF is local (openings up to 3 cells, enclosed holes): a 16 m buffer makes the tiled
    labels identical to the whole-cloud labels everywhere, seams included."""
    tiled = smrf_filter(Cloud.from_xyz(scene), config=CONFIG, tiling=TILED)
    assert tiled.diagnostics.n_tiles == 4
    np.testing.assert_array_equal(tiled.ground, whole_labels)
    _, truth = dense_scene()
    assert np.mean(whole_labels == truth) > 0.99 and not whole_labels.all()
    # the mosaic of the tile cores is the whole cloud's raster (fills agree to the solver tolerance)
    np.testing.assert_array_equal(tiled.diagnostics.object_cells, whole.diagnostics.object_cells)
    filled = ~whole.diagnostics.empty
    np.testing.assert_array_equal(tiled.diagnostics.zimin[filled], whole.diagnostics.zimin[filled])
    np.testing.assert_allclose(tiled.diagnostics.zimin, whole.diagnostics.zimin, atol=5e-3)
    np.testing.assert_allclose(tiled.diagnostics.zipro, whole.diagnostics.zipro, atol=5e-3)
    np.testing.assert_array_equal(tiled.diagnostics.origin_m, whole.diagnostics.origin_m)


def test_vmap_batch_equals_tile_by_tile(scene):
    tiles = tiling.split(scene, tile_size_m=32.0, buffer_m=16.0, cell_m=1.0)
    batch = next(batches.batches(tiles))
    assert len(batch.tiles) == 4
    ground, diag = programs.classify_batch(batch.xyz, batch.valid, batch.hw, Params(), config=CONFIG, shape=batch.shape)
    for i in range(4):
        one, one_diag = programs.classify_tile(batch.xyz[i], batch.valid[i], batch.hw[i], Params(),
                                             config=CONFIG, shape=batch.shape)
        np.testing.assert_array_equal(np.asarray(ground[i]), np.asarray(one))
        np.testing.assert_array_equal(np.asarray(diag.object_cells[i]), np.asarray(one_diag.object_cells))


def test_point_order_invariance(scene, whole_labels):
    perm = np.random.default_rng(2).permutation(len(scene))
    shuffled = smrf_filter(Cloud.from_xyz(scene[perm]), config=CONFIG, tiling=WHOLE).ground
    np.testing.assert_array_equal(shuffled, whole_labels[perm])


def test_padding_invariance(scene, whole_labels):
    """More point capacity and a larger shape bucket (padding cells outside the tile's domain)
    change no label when every domain cell holds a point."""
    tiles = tiling.split(scene, tile_size_m=500.0, buffer_m=16.0, cell_m=1.0)
    labels, _ = driver.run_batches(tiles, programs.classify_batch, Params(), CONFIG, lattice=WHOLE.lattice(1.0),
                                  max_batch=8, keep_diagnostics=False)
    np.testing.assert_array_equal(tiling.merge(len(scene), tiles, labels), whole_labels)
    batch = next(batches.batches(tiles, shape=(96, 80), capacity=2 * buckets.capacity_bucket(tiles[0].n_points)))
    ground = np.asarray(programs.classify_batch(batch.xyz, batch.valid, batch.hw, Params(), config=CONFIG,
                                              shape=batch.shape)[0])[0]
    np.testing.assert_array_equal(tiling.merge(len(scene), tiles, [ground]), whole_labels)


def test_small_batches_are_full_and_hold_every_small_tile_once():
    """Windows of a few cells (groups far apart) pad to 8-64 cells a side, many to a batch;
    every batch is full (copies of its last tile pad it), and each tile is in exactly one."""
    rng = np.random.default_rng(4)
    xyz = np.column_stack([rng.uniform(0, 30, (500, 2)), rng.normal(0, 1, 500)])
    tiles = [t for k in range(500) for t in tiling.split(xyz[k:k + 1] if k % 7 else xyz[k:k + 20],
                                                           tile_size_m=500.0, buffer_m=50.0)]
    seen = []
    for batch in batches.small_batches(tiles, max_batch=2):
        side = batch.shape[0]
        assert batch.shape == (side, side) and side in buckets.SMALL_SIDES_PX
        assert batch.xyz.shape[0] == batch.valid.shape[0] == batch.hw.shape[0] == 2 * (128 // side) ** 2
        assert batch.xyz.shape[1] == buckets.capacity_bucket(max(t.n_points for t in batch.tiles))
        for i, tile in enumerate(batch.tiles):
            assert batch.valid[i].sum() == tile.n_points and max(tile.shape) <= side
        np.testing.assert_array_equal(batch.xyz[len(batch.tiles):], np.broadcast_to(
            batch.xyz[len(batch.tiles) - 1], batch.xyz[len(batch.tiles):].shape))
        seen += [id(t) for t in batch.tiles]
    assert sorted(seen) == sorted(map(id, tiles))


def test_a_tiles_window_holds_the_points_whose_cells_window_px_names():
    """`point_cells` and `window_px` say which points `split` puts in a tile's window (a survey
    gathers exactly those: `gfjax.survey.lattice.tile_labels`), at coordinates far from 0."""
    rng = np.random.default_rng(3)
    xyz = ORIGIN + np.column_stack([rng.uniform(0, 130, 40_000), rng.uniform(0, 90, 40_000), rng.normal(0, 1, 40_000)])
    xyz[:50, :2] = np.round(xyz[:50, :2] * 4) / 4                  # points on cell edges too
    frame = Frame.of(xyz)
    tile_size_m, buffer_m, cell_m = 40.0, 7.5, 1.0
    cells = tiling.point_cells(xyz[:, :2], frame, cell_m)
    extent = tiling.extent_cells(frame, cell_m)
    made = tiling.split(xyz, tile_size_m=tile_size_m, buffer_m=buffer_m, cell_m=cell_m, frame=frame)
    assert len(made) == 12
    for tile in made:
        lo, hi, core_lo, core_hi = tiling.window_px(np.array(tile.key), extent, tile_size_m, buffer_m, cell_m)
        assert tile.window_px == tuple(lo) and tile.shape == (hi[1] - lo[1], hi[0] - lo[0])
        assert tile.core_px == (*core_lo, *core_hi)
        inside = np.flatnonzero(np.all((cells >= lo) & (cells < hi), axis=1))
        np.testing.assert_array_equal(tile.index, inside)


@pytest.mark.parametrize("rows", [61, 1000, 1 << 18])
def test_a_window_made_for_one_tile_is_that_tile_of_the_whole_split(monkeypatch, rows):
    """A survey's window names one core (`Frame.only`): it is cut a slice of points at a time,
    into exactly the tile the whole cloud's split makes, cropped windows, unused points and
    points on cell edges included; a core without a used point makes none."""
    rng = np.random.default_rng(5)
    for trial in range(12):
        n = int(rng.integers(1, 6000))
        xyz = ORIGIN + np.column_stack([rng.uniform(0, 130, n), rng.uniform(0, 90, n), rng.normal(0, 1, n)])
        xyz[:n // 3, :2] = np.round(xyz[:n // 3, :2] * 4) / 4
        if trial % 4 == 0:
            xyz[1:, :2] = xyz[:1, :2] + rng.uniform(0, 3, (n - 1, 2))     # a few cells: the window cropped
            xyz[-1, :2] += 120.0
        use = rng.random(n) > (0.0 if trial % 2 else 0.3)
        if not use.any():
            continue
        frame = Frame.of(xyz[use])
        options = dict(tile_size_m=float(rng.choice([20.0, 40.0])), buffer_m=float(rng.choice([0.0, 7.5])),
                       cell_m=float(rng.choice([0.5, 1.0])), use=use)
        whole = tiling.split(xyz, **options, frame=frame)
        monkeypatch.setattr(columns, "SLICE_ROWS", rows)
        for tile in whole:
            one, = tiling.split(xyz, **options, frame=frame.only([tile.key]))
            for field in ("key", "shape", "window_px", "core_px"):
                assert getattr(one, field) == getattr(tile, field)
            for field in ("origin_m", "index", "core", "local_xyz"):
                np.testing.assert_array_equal(getattr(one, field), getattr(tile, field))
        assert tiling.split(xyz, **options, frame=frame.only([(99, 99)])) == []
        monkeypatch.undo()
