"""`gfjax.tiling.chunks`: a window's point programs run a chunk at a time give the labels and
the rasters of one call over every point."""
from __future__ import annotations

import numpy as np
import pytest

from gfjax import pmf, smrf
from gfjax.io.cloud import Frame
from gfjax.pmf import programs as pmf_programs
from gfjax.smrf import programs as smrf_programs
from gfjax.tiling import batches, buckets, chunks
from gfjax.tiling import tiles as tiling


def test_tile_capacity_is_canonical_up_to_a_chunk_then_whole_chunks():
    chunk = buckets.POINT_CHUNK
    for n in (1, 16384, 16385, 300_000, chunk):
        assert buckets.tile_capacity(n) == buckets.canonical_capacity(n)
    assert buckets.tile_capacity(chunk + 1) == 2 * chunk
    assert buckets.tile_capacity(5_100_000) == 5 * chunk          # not 8 M slots
    assert buckets.tile_capacities() == tuple(c for c in buckets.canonical_capacities() if c <= chunk)


def _scene() -> np.ndarray:
    """A sloped, bumpy scene of 3,000 points (2,000 of them ground), float64 `(3000, 3)` [m]."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 60, (3000, 2))
    z = 0.05 * xy[:, 0] + rng.normal(0, 0.05, 3000)
    z[:1000] += rng.uniform(2, 9, 1000)                           # vegetation and roofs
    return np.column_stack([xy + 500_000.0, z])


def _batch(capacity: int):
    """One padded window of `_scene`."""
    tile, = tiling.split(_scene(), tile_size_m=100.0, buffer_m=10.0, cell_m=1.0)
    sides = buckets.canonical_sides(100.0, 10.0, 1.0)
    batch, = batches.batches([tile], max_batch=1, capacity=capacity, sides=sides)
    return batch


@pytest.mark.parametrize("package, programs, config, params", [
    ("smrf", smrf_programs, smrf.Config(window_m=6.0), smrf.Params()),
    ("pmf", pmf_programs, pmf.Config(), pmf.Params()),
])
def test_chunked_window_labels_as_one_call(monkeypatch, package, programs, config, params):
    batch = _batch(4096)
    whole_ground, whole_diag = programs.classify_batch(batch.xyz, batch.valid, batch.hw, params, config=config,
                                                       shape=batch.shape)
    monkeypatch.setattr(chunks, "POINT_CHUNK", 1024)              # four chunks of the 4,096 slots
    ground, diag = programs.classify_batch(batch.xyz, batch.valid, batch.hw, params, config=config,
                                           shape=batch.shape)
    assert isinstance(ground, np.ndarray)                         # it did run in chunks
    np.testing.assert_array_equal(ground, np.asarray(whole_ground))
    assert np.asarray(whole_ground)[0, :3000].sum() > 1000        # a real test: many ground points
    for a, b in zip(diag, whole_diag):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_capacity_of_no_whole_chunks_runs_in_one_call(monkeypatch):
    monkeypatch.setattr(chunks, "POINT_CHUNK", 1024)
    calls = []

    def program(xyz, valid):
        calls.append(xyz.shape)
        return valid
    chunks.labels(program, np.zeros((1, 1536, 3), np.float32), np.ones((1, 1536), bool))
    assert calls == [(1, 1536, 3)]


@pytest.mark.parametrize("package, programs, config, params", [
    ("smrf", smrf_programs, smrf.Config(window_m=6.0), smrf.Params()),
    ("pmf", pmf_programs, pmf.Config(), pmf.Params()),
])
def test_a_lone_window_run_in_chunks_is_not_copied_and_labels_as_padded(monkeypatch, package, programs, config,
                                                                      params):
    """A filter's lone window that runs a chunk at a time passes its own points, unpadded (no
    second copy of a survey's millions): the labels and rasters of the padded batch."""
    padded = _batch(4096)
    monkeypatch.setattr(chunks, "POINT_CHUNK", 1024)
    tile, = padded.tiles
    shared, = batches.batches([tile], max_batch=1, capacity=4096, sides=buckets.canonical_sides(100.0, 10.0, 1.0))
    assert shared.xyz.shape == (1, tile.n_points, 3) and np.shares_memory(shared.xyz, tile.local_xyz)
    assert shared.valid.shape == (1, 4096)
    ground, diag = programs.classify_batch(shared.xyz, shared.valid, shared.hw, params, config=config,
                                           shape=shared.shape)
    want_ground, want_diag = programs.classify_batch(padded.xyz, padded.valid, padded.hw, params, config=config,
                                                     shape=padded.shape)
    np.testing.assert_array_equal(ground, want_ground)
    for a, b in zip(diag, want_diag):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    tuned, = batches.batches([tile], max_batch=1, capacity=4096)          # tuning's batches: always padded
    assert tuned.xyz.shape == (1, 4096, 3)


@pytest.mark.parametrize("package, programs, config, params", [
    ("smrf", smrf_programs, smrf.Config(window_m=6.0), smrf.Params()),
    ("pmf", pmf_programs, pmf.Config(), pmf.Params()),
])
def test_a_survey_window_made_a_chunk_at_a_time_labels_as_padded(monkeypatch, package, programs, config, params):
    """A survey's window (a frame naming one core) holds no float32 copy of its points: they
    are made a chunk at a time (`WindowRows`), with the labels and rasters of the padded batch."""
    xyz = _scene()
    monkeypatch.setattr(chunks, "POINT_CHUNK", 1024)
    frame = Frame.of(xyz)
    lattice = dict(tile_size_m=100.0, buffer_m=10.0, cell_m=1.0)
    for use in (None, np.arange(len(xyz)) % 7 > 0):                  # every point in order, or some
        tile, = tiling.split(xyz, **lattice, use=use, frame=frame.only([(0, 0)]))
        assert isinstance(tile.local_xyz, tiling.WindowRows)
        assert isinstance(tile.index, range) == (use is None)
        same, = tiling.split(xyz, **lattice, use=use, frame=frame)     # the multi-tile cut, made whole
        np.testing.assert_array_equal(np.asarray(tile.local_xyz), same.local_xyz)
        np.testing.assert_array_equal(tile.local_xyz.rows(slice(1000, 2100)), same.local_xyz[1000:2100])
        streamed, = batches.batches([tile], max_batch=1, capacity=4096, sides=buckets.canonical_sides(100.0, 10.0, 1.0))
        assert streamed.xyz is tile.local_xyz
        padded, = batches.batches([same], max_batch=1, capacity=4096, sides=buckets.canonical_sides(100.0, 10.0, 1.0))
        ground, diag = programs.classify_batch(streamed.xyz, streamed.valid, streamed.hw, params, config=config,
                                               shape=streamed.shape)
        want_ground, want_diag = programs.classify_batch(padded.xyz, padded.valid, padded.hw, params, config=config,
                                                         shape=padded.shape)
        np.testing.assert_array_equal(ground, want_ground)
        assert np.asarray(want_ground)[0, :tile.n_points].sum() > 1000          # many ground points
        for a, b in zip(diag, want_diag):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        labels = np.asarray(ground)[0, :tile.n_points]
        np.testing.assert_array_equal(tiling.merge(len(xyz), [tile], [labels]),
                                      tiling.merge(len(xyz), [same], [labels]))
