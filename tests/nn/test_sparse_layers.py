"""voxelize / devoxelize, the map pyramid, and the equinox layers."""
from __future__ import annotations

import doctest

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax.nn import sparse

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)


def cloud(n=400, seed=0, extent=6.0):
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-extent, extent, (n, 3)).astype(np.float32)
    xyz[:, 2] *= 0.3
    return xyz


def test_docstring_example_runs():
    result = doctest.testmod(sparse, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 5 and result.failed == 0


def test_voxelize_means_and_point_voxel_match_numpy():
    xyz = cloud()
    feats = np.random.default_rng(1).standard_normal((len(xyz), 2)).astype(np.float32)
    valid = np.random.default_rng(2).random(len(xyz)) < 0.9
    vox = sparse.voxelize(xyz, feats, np.zeros(len(xyz), np.int32), 1.5, valid=valid)
    grid = np.floor(xyz / np.float32(1.5)).astype(np.int32)
    uniq, inverse = np.unique(grid[valid], axis=0, return_inverse=True)
    t = vox.tensor
    n = int(np.sum(np.asarray(t.valid)))
    assert n == len(uniq) and not bool(vox.overflowed)
    np.testing.assert_array_equal(np.asarray(t.coords)[:n, 1:], uniq)          # sorted (i, j, k) order
    pv = np.asarray(vox.point_voxel)
    assert np.all(pv[~valid] == -1)
    np.testing.assert_array_equal(pv[valid], inverse.ravel())
    expected = np.stack([np.bincount(inverse.ravel(), feats[valid][:, c]) for c in range(2)], 1)
    expected /= np.bincount(inverse.ravel())[:, None]
    np.testing.assert_allclose(np.asarray(t.feats)[:n], expected, rtol=1e-5, atol=1e-6)
    assert np.all(np.asarray(t.feats)[n:] == 0)
    back = np.asarray(sparse.devoxelize(t.feats, vox.point_voxel))
    np.testing.assert_array_equal(back[valid], np.asarray(t.feats)[pv[valid]])
    assert np.all(back[~valid] == 0)


def test_voxelize_overflow_and_bad_input(unchecked):
    xyz = cloud(100)
    vox = sparse.voxelize(xyz, xyz, 0, 0.5, capacity=4)
    assert bool(vox.overflowed) and np.sum(np.asarray(vox.point_voxel) >= 0) < 100
    with pytest.raises(ValueError, match="voxel_m must be > 0"):
        sparse.voxelize(xyz, xyz, 0, 0.0)
    with pytest.raises(ValueError, match=r"points must have shape \(n, 3\)"):
        sparse.voxelize(xyz[:, :2], xyz, 0, 1.0)
    far = xyz.copy()
    far[0, 0] = 1e5
    with pytest.raises(ValueError, match="voxelize: voxel coordinates must lie in"):
        sparse.voxelize(far, far, 0, 0.5)


def test_pyramid_maps_equal_maps_built_one_by_one():
    xyz = cloud(300, seed=3)
    vox = sparse.voxelize(xyz, xyz, 0, 0.5)
    t = vox.tensor
    plan = sparse.plan_pyramid(t.coords, t.valid, depth=2)
    pyr = jax.jit(sparse.build_pyramid, static_argnums=2)(t.coords, t.valid, plan)
    assert not bool(pyr.overflowed)
    assert [int(np.sum(np.asarray(v))) for v in pyr.valid][0] == int(np.sum(np.asarray(t.valid)))
    c, v = t.coords, t.valid
    for level in range(2):
        coarse, cv, _ = sparse.downsample(c, v, capacity=plan.capacities[level + 1])
        np.testing.assert_array_equal(np.asarray(coarse), np.asarray(pyr.coords[level + 1]))
        down = sparse.strided_map(c, v, coarse, cv)
        assert int(down.n_pairs) == int(pyr.down[level].n_pairs) == int(np.sum(np.asarray(v)))
        sub = sparse.submanifold_map(c, v)
        assert int(sub.n_pairs) == int(pyr.submanifold[level].n_pairs)
        c, v = coarse, cv
    stem = np.asarray(pyr.stem.table)
    assert int(np.sum(stem < stem.shape[0])) == int(sparse.submanifold_map(t.coords, t.valid, kernel_size=5).n_pairs)
    small = plan._replace(capacities=(plan.capacities[0], 2) + plan.capacities[2:])
    assert bool(sparse.build_pyramid(t.coords, t.valid, small).overflowed)


def test_plan_union_holds_both():
    a = sparse.plan_pyramid(*_coords(cloud(300, seed=4)), depth=2)
    b = sparse.plan_pyramid(*_coords(cloud(300, seed=5, extent=3.0)), depth=2)
    u = a.union(b)
    assert all(x >= max(p, q) for x, p, q in zip(u.capacities, a.capacities, b.capacities))
    for m, p, q in zip(u.submanifold, a.submanifold, b.submanifold):
        assert m[0] * m[1] >= max(p[0] * p[1], q[0] * q[1])


def _coords(xyz):
    t = sparse.voxelize(xyz, xyz, 0, 0.5).tensor
    return t.coords, t.valid


def test_group_norm_matches_numpy_per_sample():
    rng = np.random.default_rng(6)
    feats = rng.standard_normal((50, 8)).astype(np.float32) * 3 + 1
    batch = np.repeat([0, 1], 25)
    valid = rng.random(50) < 0.8
    coords = np.concatenate([batch[:, None], rng.integers(0, 9, (50, 3))], 1).astype(np.int32)
    x = sparse.SparseTensor(jnp.asarray(coords), jnp.asarray(np.where(valid[:, None], feats, 0)), jnp.asarray(valid),
                            batch_size=2)
    out = np.asarray(eqx.filter_jit(sparse.SparseGroupNorm(8, groups=4))(x).feats)
    for b in (0, 1):
        rows = valid & (batch == b)
        g = feats[rows].reshape(-1, 4, 2)
        ref = (g - g.mean(axis=(0, 2), keepdims=True)) / np.sqrt(g.var(axis=(0, 2), keepdims=True) + 1e-5)
        np.testing.assert_allclose(out[rows], ref.reshape(-1, 8), rtol=1e-4, atol=1e-4)
    assert np.all(out[~valid] == 0)


def test_weighted_group_norm_equals_rows_repeated_by_their_weight():
    rng = np.random.default_rng(8)
    feats = rng.standard_normal((40, 4)).astype(np.float32)
    weight = rng.integers(0, 4, 40).astype(np.float32)
    coords = np.zeros((40, 4), np.int32)
    coords[:, 0] = np.repeat([0, 1], 20)
    norm = sparse.SparseGroupNorm(4, groups=2)
    x = sparse.SparseTensor(jnp.asarray(coords), jnp.asarray(feats), jnp.ones(40, bool), batch_size=2)
    out = np.asarray(eqx.filter_jit(lambda n, x, w: n(x, w))(norm, x, jnp.asarray(weight)).feats)
    rep = np.repeat(np.arange(40), weight.astype(int))
    xr = sparse.SparseTensor(jnp.asarray(coords[rep]), jnp.asarray(feats[rep]), jnp.ones(len(rep), bool), batch_size=2)
    ref = np.asarray(norm(xr).feats)
    first = {r: i for i, r in reversed(list(enumerate(rep)))}
    rows = np.flatnonzero(weight > 0)
    np.testing.assert_allclose(out[rows], ref[[first[r] for r in rows]], rtol=1e-4, atol=1e-5)


def test_pyramid_parent_rows_hold_each_voxel():
    xyz = cloud(500, seed=9, extent=8.0)
    coords, valid = _coords(xyz)
    plan = sparse.plan_pyramid(coords, valid, depth=3)
    pyramid = jax.jit(sparse.build_pyramid, static_argnums=2)(coords, valid, plan)
    for level in range(3):
        fine, fine_valid = np.asarray(pyramid.coords[level]), np.asarray(pyramid.valid[level])
        coarse = np.asarray(pyramid.coords[level + 1])
        parent = np.asarray(pyramid.parent(level))
        np.testing.assert_array_equal(coarse[parent[fine_valid], 1:], np.floor_divide(fine[fine_valid, 1:], 2))
        assert np.all(np.asarray(pyramid.valid[level + 1])[parent[fine_valid]])


def test_layers_jit_grad_and_residual_identity_at_init():
    xyz = cloud(300, seed=7)
    vox = sparse.voxelize(xyz, xyz, 0, 0.5)
    x = vox.tensor
    plan = sparse.plan_pyramid(x.coords, x.valid, depth=1)
    pyr = sparse.build_pyramid(x.coords, x.valid, plan)
    keys = jax.random.split(jax.random.key(0), 4)
    stem = sparse.SparseConv3d(3, 8, 5, key=keys[0])
    block, state = eqx.nn.make_with_state(sparse.SparseResBlock)(8, 8, key=keys[1])
    down = sparse.SparseConv3d(8, 16, 2, stride=2, key=keys[2])
    up = sparse.SparseConv3d(16, 8, 2, stride=2, transposed=True, key=keys[3])
    h = stem(x, pyr.stem)
    # the second norm starts at scale 0: a new residual block is relu(identity)
    out, _ = block(h, pyr.submanifold[0], jax.tree.map(lambda a: a, state))       # a state is used once
    np.testing.assert_allclose(np.asarray(out.feats), np.asarray(jax.nn.relu(h.feats)), rtol=1e-6, atol=1e-6)

    @eqx.filter_jit
    def loss(layers, x):
        stem, block, down, up = layers
        h, _ = block(stem(x, pyr.stem), pyr.submanifold[0], state)
        coarse = down(h, pyr.down[0])
        assert coarse.stride == 2 and coarse.capacity == plan.capacities[1]
        fine = up(coarse, pyr.up(0))
        assert fine.stride == 1 and fine.capacity == x.capacity
        return jnp.sum(fine.feats ** 2) + jnp.sum(h.feats)

    grads = eqx.filter_grad(loss)((stem, block, down, up), x)
    leaves = jax.tree_util.tree_leaves(eqx.filter(grads, eqx.is_array))
    assert all(np.all(np.isfinite(np.asarray(g))) for g in leaves)
    assert np.any(np.asarray(grads[0].weight) != 0) and np.any(np.asarray(grads[2].weight) != 0)


def test_batch_norm_statistics_in_training_and_inference():
    rng = np.random.default_rng(10)
    feats = rng.standard_normal((60, 3)).astype(np.float32) * [1, 4, 0.5] + [2, -1, 0]
    valid = rng.random(60) < 0.8
    weight = rng.integers(0, 3, 60).astype(np.float32)
    x = sparse.SparseTensor(jnp.zeros((60, 4), jnp.int32), jnp.asarray(np.where(valid[:, None], feats, 0)),
                            jnp.asarray(valid), batch_size=2)
    norm, state = eqx.nn.make_with_state(sparse.SparseBatchNorm)(3, momentum=0.25)
    out, new = eqx.filter_jit(lambda n, x, s, w: n(x, s, w))(norm, x, state, jnp.asarray(weight))
    rows = np.repeat(np.flatnonzero(valid), weight[valid].astype(int))          # rows counted w times
    mean, var = feats[rows].mean(axis=0), feats[rows].var(axis=0)
    np.testing.assert_allclose(np.asarray(out.feats)[valid], (feats[valid] - mean) / np.sqrt(var + 1e-5),
                               rtol=1e-4, atol=1e-4)
    assert np.all(np.asarray(out.feats)[~valid] == 0)
    running_mean, running_var = new.get(norm.index)
    np.testing.assert_allclose(np.asarray(running_mean), 0.25 * mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(running_var), 0.75 + 0.25 * var * len(rows) / (len(rows) - 1), rtol=1e-5)
    # inference: the running statistics, one affine map for every row whatever its batch
    fixed, same = eqx.nn.inference_mode(norm)(x, new)
    np.testing.assert_allclose(np.asarray(fixed.feats)[valid],
                               (feats[valid] - np.asarray(running_mean)) / np.sqrt(np.asarray(running_var) + 1e-5),
                               rtol=1e-5, atol=1e-5)
    assert same is new


def test_conv_rejects_a_map_of_another_kernel():
    xyz = cloud(50)
    x = sparse.voxelize(xyz, xyz, 0, 1.0).tensor
    with pytest.raises(ValueError, match="kernel 5 needs a map of 125 offsets"):
        sparse.SparseConv3d(3, 4, 5, key=jax.random.key(0))(x, sparse.submanifold_map(x.coords, x.valid))


def test_he_initialisation_scale():
    conv = sparse.SparseConv3d(32, 64, 3, key=jax.random.key(0))
    std = float(np.std(np.asarray(conv.weight)))
    assert abs(std - np.sqrt(2.0 / (27 * 64))) < 0.05 * np.sqrt(2.0 / (27 * 64))
