"""SparseGF's host pipeline: voxels, context thinning, packing, the shifted partition grid."""
from __future__ import annotations

import numpy as np
import pytest

from gfjax.nn import sparse
from gfjax.sparsegf import pipeline
from gfjax.sparsegf.partition import PartitionConfig, partition
from gfjax.tiling.buckets import power_bucket


def test_host_voxels_equal_the_jax_voxelize():
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-20, 20, (3000, 3)).astype(np.float32)
    feats = rng.standard_normal((3000, 5)).astype(np.float32)
    coords, mean, row = pipeline.voxelize(xyz, feats, 0.5)
    ref = sparse.voxelize(xyz, feats, 0, 0.5)
    n = int(np.sum(np.asarray(ref.tensor.valid)))
    np.testing.assert_array_equal(coords, np.asarray(ref.tensor.coords)[:n, 1:])
    np.testing.assert_allclose(mean, np.asarray(ref.tensor.feats)[:n], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(row, np.asarray(ref.point_voxel))


def test_thinning_keeps_every_central_point_and_is_seeded():
    central = np.zeros(1000, bool)
    central[::7] = True
    keep = pipeline.thin_context(central, 300, seed=4)
    assert len(keep) == central.sum() + 300 and central[keep].sum() == central.sum()
    np.testing.assert_array_equal(keep, pipeline.thin_context(central, 300, seed=4))
    assert not np.array_equal(keep, pipeline.thin_context(central, 300, seed=5))
    np.testing.assert_array_equal(pipeline.thin_context(central, 1000 - central.sum(), seed=4), np.arange(1000))


def fake_patch(m, c, pid):
    coords = np.column_stack([np.arange(m) % 256, np.arange(m) // 256, np.zeros(m)]).astype(np.int32)
    return pipeline.Patch(coords, np.ones((m, 2), np.float32), np.arange(c), np.arange(c) % m,
                          np.full((c, 2), pid, np.float32), pid)


def test_packs_hold_at_most_their_slots_and_voxels_in_order():
    found = [fake_patch(m, 3, i) for i, m in enumerate([100, 200, 30_000, 40_000, 70_000, 10, 10])]
    groups = list(pipeline.group(found, 3, max_voxels=65_536))
    assert [[p.patch_id for p in g] for g in groups] == [[0, 1, 2], [3], [4], [5, 6]]
    packed = pipeline.pack(groups[0], 3)
    assert packed.coords.shape == (power_bucket(30_300, minimum=pipeline.PACK_VOXELS), 4) and packed.slots == 3
    np.testing.assert_array_equal(packed.starts, [0, 100, 300])
    np.testing.assert_array_equal(packed.coords[:30_300, 0], np.repeat([0, 1, 2], [100, 200, 30_000]))
    assert packed.valid.sum() == 30_300 and packed.weight.sum() == 9
    assert len(packed.point_row) == pipeline.POINTS_PER_VOXEL * len(packed.coords) and packed.point_valid.sum() == 9
    np.testing.assert_array_equal(packed.point_starts, [0, 3, 6])
    np.testing.assert_array_equal(packed.point_row[:9], np.repeat(packed.starts, 3) + np.tile(np.arange(3), 3))
    np.testing.assert_array_equal(packed.point_feats[:9, 0], np.repeat([0, 1, 2], 3))
    np.testing.assert_array_equal(packed.per_point([np.arange(3), np.arange(3) + 3, np.arange(3) + 6])[:10],
                                  [0, 1, 2, 3, 4, 5, 6, 7, 8, 0])
    assert pipeline.pack(groups[2], 3).coords.shape[0] == 131_072        # a patch larger than a pack alone
    with pytest.raises(ValueError, match="1..3 patches"):
        pipeline.pack(found[:4], 3)


def test_packs_hold_at_most_their_share_of_central_points():
    per_pack = pipeline.POINTS_PER_VOXEL * 1_000
    found = [fake_patch(10, c, i) for i, c in enumerate([per_pack // 2, per_pack // 2, 1, pipeline.POINTS_PER_VOXEL * 1_024 + 5])]
    groups = list(pipeline.group(found, 8, max_voxels=1_000))
    assert [[p.patch_id for p in g] for g in groups] == [[0, 1], [2], [3]]
    assert len(pipeline.pack(groups[2], 8, min_capacity=1_024).point_row) == 2 * pipeline.POINTS_PER_VOXEL * 1_024


def test_central_counts_per_voxel():
    p = pipeline.Patch(np.zeros((4, 3), np.int32), np.zeros((4, 1), np.float32), np.arange(5),
                       np.array([0, 0, 2, 3, 3]), np.zeros((5, 1), np.float32), 0)
    np.testing.assert_array_equal(p.central_counts(), [2, 0, 1, 2])


@pytest.mark.parametrize("shift", [(0.0, 0.0), (12.5, 40.0), (49.9, 0.1)])
def test_a_shifted_grid_still_covers_every_point(shift):
    rng = np.random.default_rng(1)
    xyz = np.column_stack([rng.uniform(0, 230, (4000, 2)), rng.uniform(0, 5, 4000)]) + [6e5, 5e6, 0]
    config = PartitionConfig()
    part = partition(xyz, config, shift_m=shift)
    d = np.hypot(*(xyz[:, None, :2] - part.centers_m[None]).transpose(2, 0, 1))
    assert np.all(d.min(axis=1) <= config.r_in_m + 1e-3)
    if shift != (0.0, 0.0):
        base = partition(xyz, config).centers_m
        offsets = np.mod(part.centers_m[:, None] - base[None], config.step_m)
        np.testing.assert_allclose(offsets[:, 0], np.broadcast_to(np.mod(shift, config.step_m), offsets[:, 0].shape),
                                   atol=1e-6)


def test_a_cloud_with_few_voxels_packs_into_the_tiny_capacity_and_only_such_a_cloud():
    few, some, many = [fake_patch(30, 3, 0)], [fake_patch(5_000, 3, 0)], [fake_patch(9_000, 3, 0)]
    tiny, small, full = pipeline.TINY_PACK_VOXELS, pipeline.SMALL_PACK_VOXELS, pipeline.PACK_VOXELS
    assert pipeline.min_capacity(few, cloud_voxels_at_most=30) == tiny
    assert pipeline.min_capacity(few, cloud_voxels_at_most=tiny) == tiny
    # the last few voxels of a larger cloud keep the capacity they had
    assert pipeline.min_capacity(few, cloud_voxels_at_most=tiny + 1) == small
    assert pipeline.min_capacity(some, cloud_voxels_at_most=50_000) == small
    assert pipeline.min_capacity(many, cloud_voxels_at_most=50_000) == full
    assert pipeline.pack(few, 4, min_capacity=tiny).coords.shape == (tiny, 4)



def test_a_patch_a_window_holds_whole_is_the_whole_clouds_patch_thinned_alike():
    # context thinned (at most 1,000 points a patch): a window laid on the cloud's frame, its
    # points in another order (a survey's window lists its own file's first), prepares the
    # patches it holds whole exactly as the whole cloud does, same thinning
    import sys

    from gfjax.io.cloud import Frame
    from gfjax.sparsegf import Config

    patches = sys.modules["gfjax.sparsegf.filter"].patches
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 420, (6000, 2))
    xyz = np.column_stack([xy + [512_000.0, 5_400_000.0], 100 + rng.normal(0, 0.3, len(xy))])
    config = Config(features="xyz", max_context_points=1_000)
    frame = Frame.of(xyz)
    whole = {p.patch_id: p for p in patches(xyz, config, frame=frame)}
    inside = rng.permutation(np.flatnonzero(xy[:, 0] <= 330))
    held = 0
    for patch in patches(xyz[inside], config, frame=frame):
        mine = whole[patch.patch_id]
        centre_x = xy[inside[patch.point_index], 0].mean()
        if centre_x + 150 + 36 < 330:            # its cylinder lies inside the window
            np.testing.assert_array_equal(inside[patch.point_index], mine.point_index)
            np.testing.assert_array_equal(patch.coords, mine.coords)
            np.testing.assert_array_equal(patch.feats, mine.feats)
            held += 1
    assert held >= 4
