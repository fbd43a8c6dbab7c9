"""Sparse convolution against dense `lax.conv_general_dilated` on small grids, under jit and vmap."""
from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax
from jax.test_util import check_grads

from gfjax.nn import sparse
from gfjax.nn.sparse import keys as K
from gfjax.nn.sparse.maps import kernel_offsets, neighbour_table

SHAPE = (6, 4, 4)          # dense test grid (i, j, k), even so that stride 2 covers it
C_IN, C_OUT = 3, 4


def grid_coords(shape, batch=0):
    ijk = np.asarray(list(itertools.product(*(range(s) for s in shape))), np.int32)
    return np.concatenate([np.full((len(ijk), 1), batch, np.int32), ijk], axis=1)


def sparse_sites(density, *, seed=0, shape=SHAPE):
    """Occupied voxels of `shape` (at least one), and their features."""
    rng = np.random.default_rng(seed)
    coords = grid_coords(shape)
    keep = rng.random(len(coords)) < density
    keep[rng.integers(len(coords))] = True
    coords = coords[keep]
    feats = rng.standard_normal((len(coords), C_IN)).astype(np.float32)
    return coords, feats


def to_dense(coords, feats, shape=SHAPE):
    dense = np.zeros(shape + (feats.shape[1],), np.float32)
    dense[coords[:, 1], coords[:, 2], coords[:, 3]] = feats
    return dense


def dense_kernel(weight, kernel_size):
    """(k**3, c, d) in lexicographic offset order -> DHWIO."""
    return jnp.reshape(weight, (kernel_size,) * 3 + weight.shape[1:])


def dense_conv(x, w_dhwio, *, stride=1, padding="SAME"):
    out = lax.conv_general_dilated(x[None], w_dhwio, (stride,) * 3, padding,
                                   dimension_numbers=("NDHWC", "DHWIO", "NDHWC"),
                                   precision=lax.Precision.HIGHEST)
    return out[0]


def weights(kernel_size, seed=1, c_in=C_IN, c_out=C_OUT):
    return jax.random.normal(jax.random.key(seed), (kernel_size ** 3, c_in, c_out), jnp.float32)


CASES = [("full", 1.0, 3), ("half", 0.5, 3), ("sparse", 0.15, 3), ("one_voxel", 0.0, 3),
         ("full_k5", 1.0, 5), ("sparse_k5", 0.3, 5), ("k1", 0.4, 1)]


@pytest.mark.parametrize("name,density,kernel_size", CASES, ids=[c[0] for c in CASES])
def test_submanifold_equals_dense_at_occupied_sites(name, density, kernel_size):
    coords, feats = sparse_sites(density)
    valid = np.ones(len(coords), bool)
    w = weights(kernel_size)
    kmap = sparse.submanifold_map(coords, valid, kernel_size=kernel_size)
    got = jax.jit(sparse.sparse_conv)(jnp.asarray(feats), w, kmap)
    expected = dense_conv(jnp.asarray(to_dense(coords, feats)), dense_kernel(w, kernel_size))
    np.testing.assert_allclose(got, np.asarray(expected)[coords[:, 1], coords[:, 2], coords[:, 3]],
                               rtol=1e-5, atol=1e-5)
    assert not bool(kmap.overflowed)


def test_pairs_count_only_existing_neighbours():
    coords, _ = sparse_sites(0.3)
    kmap = sparse.submanifold_map(coords, np.ones(len(coords), bool))
    present = {tuple(c[1:]) for c in coords}
    brute = sum((c[1] + di, c[2] + dj, c[3] + dk) in present
                for c in coords for di, dj, dk in itertools.product((-1, 0, 1), repeat=3))
    assert int(kmap.n_pairs) == brute
    assert int(np.sum(np.asarray(kmap.in_idx) < kmap.n_in)) == brute


@pytest.mark.parametrize("density", [1.0, 0.3], ids=["full", "sparse"])
def test_strided_equals_dense_stride_2(density):
    coords, feats = sparse_sites(density, seed=3)
    valid = np.ones(len(coords), bool)
    coarse, coarse_valid, overflowed = sparse.downsample(coords, valid, capacity=len(coords))
    kmap = sparse.strided_map(coords, valid, coarse, coarse_valid)
    w = weights(2)
    got = np.asarray(jax.jit(sparse.sparse_conv)(jnp.asarray(feats), w, kmap))
    expected = np.asarray(dense_conv(jnp.asarray(to_dense(coords, feats)), dense_kernel(w, 2), stride=2, padding="VALID"))
    cv = np.asarray(coarse_valid)
    c = np.asarray(coarse)[cv]
    expected_sites = {tuple(x) for x in np.unique(coords[:, 1:] // 2, axis=0)}
    assert {tuple(x) for x in c[:, 1:]} == expected_sites and not bool(overflowed)
    np.testing.assert_allclose(got[cv], expected[c[:, 1], c[:, 2], c[:, 3]], rtol=1e-5, atol=1e-5)
    assert np.all(got[~cv] == 0)


@pytest.mark.parametrize("density", [1.0, 0.3], ids=["full", "sparse"])
def test_transposed_is_the_adjoint_of_strided(density):
    """The transposed map takes each coarse voxel back to its children, weight d for offset d:
    the dense equivalent is the vector-Jacobian product of the stride-2 convolution."""
    coords, _ = sparse_sites(density, seed=4)
    valid = np.ones(len(coords), bool)
    coarse, coarse_valid, _ = sparse.downsample(coords, valid, capacity=len(coords))
    up = sparse.strided_map(coords, valid, coarse, coarse_valid).transpose()
    cv = np.asarray(coarse_valid)
    rng = np.random.default_rng(5)
    y = np.where(cv[:, None], rng.standard_normal((len(cv), C_OUT)), 0).astype(np.float32)
    w = weights(2, c_in=C_OUT, c_out=C_IN)                         # (8, coarse channels, fine channels)
    got = np.asarray(jax.jit(sparse.sparse_conv)(jnp.asarray(y), w, up))

    w_fwd = dense_kernel(jnp.swapaxes(w, 1, 2), 2)                   # strided conv fine -> coarse
    zero = jnp.zeros(SHAPE + (C_IN,), jnp.float32)
    _, vjp = jax.vjp(lambda x: dense_conv(x, w_fwd, stride=2, padding="VALID"), zero)
    c = np.asarray(coarse)[cv]
    y_dense = np.zeros(tuple(s // 2 for s in SHAPE) + (C_OUT,), np.float32)
    y_dense[c[:, 1], c[:, 2], c[:, 3]] = y[cv]
    expected = np.asarray(vjp(jnp.asarray(y_dense))[0])
    np.testing.assert_allclose(got, expected[coords[:, 1], coords[:, 2], coords[:, 3]], rtol=1e-5, atol=1e-5)


def test_negative_coordinates_and_odd_strides():
    """floor(coord / 2) for negative coordinates: (-1, -2) share a parent, (-1, 0) do not."""
    coords = np.asarray([[0, -1, 0, 0], [0, -2, 0, 0], [0, 0, 0, 0], [0, -3, -5, 7]], np.int32)
    coarse, cv, _ = sparse.downsample(coords, np.ones(4, bool), capacity=4)
    got = {tuple(c) for c in np.asarray(coarse)[np.asarray(cv)]}
    assert got == {(0, -1, 0, 0), (0, 0, 0, 0), (0, -2, -3, 3)}


@pytest.mark.parametrize("spare", [1, 4], ids=["tight", "mostly_padding"])
def test_scan_and_all_at_once_are_exact(spare):
    """Every schedule gives the same bits, also where most blocks are padding (skipped steps)."""
    coords, feats = sparse_sites(0.5, seed=6, shape=(9, 8, 7))
    valid = np.ones(len(coords), bool)
    block, n_blocks = sparse.plan_blocks(np.asarray(sparse.pairs_per_offset(
        neighbour_table(coords, valid, coords, valid, kernel_size=3), len(coords))), block=16)
    kmap = sparse.submanifold_map(coords, valid, block=block, n_blocks=spare * n_blocks)
    w = weights(3)
    whole = jax.jit(lambda f, w, m: sparse.sparse_conv(f, w, m, chunk_blocks=0))(jnp.asarray(feats), w, kmap)
    for chunk in (None, 1, 3, n_blocks - 1, spare * n_blocks + 5):
        chunked = jax.jit(lambda f, w, m, c=chunk: sparse.sparse_conv(f, w, m, chunk_blocks=c))(jnp.asarray(feats), w, kmap)
        np.testing.assert_array_equal(np.asarray(whole), np.asarray(chunked))


def test_negative_chunk_is_refused():
    coords, feats = sparse_sites(0.5, seed=6)
    kmap = sparse.submanifold_map(coords, np.ones(len(coords), bool))
    with pytest.raises(ValueError, match="chunk_blocks must be >= 0"):
        sparse.sparse_conv(jnp.asarray(feats), weights(3), kmap, chunk_blocks=-1)


def test_gradients_match_finite_differences():
    coords, feats = sparse_sites(0.4, seed=7, shape=(4, 4, 3))
    kmap = sparse.submanifold_map(coords, np.ones(len(coords), bool))
    w = weights(3)
    jax.config.update("jax_enable_x64", True)
    try:
        f64, w64 = jnp.asarray(feats, jnp.float64), jnp.asarray(w, jnp.float64)
        check_grads(lambda f, w: sparse.sparse_conv(f, w, kmap), (f64, w64), order=2, modes=("rev",))
        check_grads(lambda f, w: sparse.sparse_conv(f, w, kmap, chunk_blocks=1), (f64, w64), order=1, modes=("rev",))
        roomy = sparse.submanifold_map(coords, np.ones(len(coords), bool), block=kmap.block, n_blocks=4 * kmap.n_blocks)
        check_grads(lambda f, w: sparse.sparse_conv(f, w, roomy, chunk_blocks=1), (f64, w64), order=1, modes=("rev",))
    finally:
        jax.config.update("jax_enable_x64", False)


def with_padding(coords, feats, n_pad, *, seed=8):
    """Padding rows whose coordinates duplicate valid ones and whose features are garbage."""
    rng = np.random.default_rng(seed)
    pad_c = coords[rng.integers(0, len(coords), n_pad)]
    pad_f = (1e6 * rng.standard_normal((n_pad, feats.shape[1]))).astype(np.float32)
    valid = np.concatenate([np.ones(len(coords), bool), np.zeros(n_pad, bool)])
    return np.concatenate([coords, pad_c]), np.concatenate([feats, pad_f]), valid


def test_padding_rows_never_change_a_valid_output():
    coords, feats = sparse_sites(0.5, seed=9)
    w = weights(3)
    ref = sparse.sparse_conv(jnp.asarray(feats), w, sparse.submanifold_map(coords, np.ones(len(coords), bool)))
    pc, pf, pv = with_padding(coords, feats, 37)
    got = sparse.sparse_conv(jnp.asarray(pf), w, sparse.submanifold_map(pc, pv))
    np.testing.assert_array_equal(np.asarray(got)[: len(coords)], np.asarray(ref))
    assert np.all(np.asarray(got)[len(coords):] == 0)


def test_shuffled_rows_give_the_same_outputs_in_the_same_order():
    coords, feats = sparse_sites(0.5, seed=10)
    w = weights(3)
    ref = np.asarray(sparse.sparse_conv(jnp.asarray(feats), w, sparse.submanifold_map(coords, np.ones(len(coords), bool))))
    perm = np.random.default_rng(11).permutation(len(coords))
    got = np.asarray(sparse.sparse_conv(jnp.asarray(feats[perm]), w,
                                        sparse.submanifold_map(coords[perm], np.ones(len(coords), bool))))
    np.testing.assert_allclose(got, ref[perm], rtol=1e-6, atol=1e-6)


def test_vmap_and_batch_index_equal_one_tensor_at_a_time():
    w = weights(3)
    samples = [sparse_sites(d, seed=s) for s, d in ((12, 0.3), (13, 0.6), (14, 0.1))]
    cap = max(len(c) for c, _ in samples)
    padded = [with_padding(c, f, cap - len(c)) if len(c) < cap else (c, f, np.ones(cap, bool)) for c, f in samples]
    one_by_one = [np.asarray(sparse.sparse_conv(jnp.asarray(f), w, sparse.submanifold_map(c, np.ones(len(c), bool))))
                  for c, f in samples]

    block, n_blocks = 16, 27 * (-(-cap // 16))
    stacked = [jnp.asarray(np.stack(a)) for a in zip(*padded)]

    def one(c, f, v):
        return sparse.sparse_conv(f, w, sparse.submanifold_map(c, v, block=block, n_blocks=n_blocks))

    batched = np.asarray(jax.jit(jax.vmap(one))(*stacked))
    for b, ref in enumerate(one_by_one):
        np.testing.assert_allclose(batched[b, : len(ref)], ref, rtol=1e-6, atol=1e-6)

    # the same samples in one tensor, told apart by the batch column
    coords = np.concatenate([np.concatenate([np.full((len(c), 1), b, np.int32), c[:, 1:]], 1)
                             for b, (c, _) in enumerate(samples)])
    feats = np.concatenate([f for _, f in samples])
    joint = np.asarray(sparse.sparse_conv(jnp.asarray(feats), w, sparse.submanifold_map(coords, np.ones(len(coords), bool))))
    np.testing.assert_allclose(joint, np.concatenate(one_by_one), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("n", [0, 5], ids=["no_rows", "all_padding"])
def test_empty_tensor_gives_zero_rows(n):
    coords, valid = np.zeros((n, 4), np.int32), np.zeros(n, bool)
    kmap = sparse.submanifold_map(coords, valid)
    out = jax.jit(sparse.sparse_conv)(jnp.ones((n, C_IN), jnp.float32), weights(3), kmap)
    assert out.shape == (n, C_OUT) and np.all(np.asarray(out) == 0)
    coarse, cv, _ = sparse.downsample(coords, valid, capacity=max(n, 1))
    assert not np.any(np.asarray(cv))
    down = sparse.strided_map(coords, valid, coarse, cv)
    assert int(down.n_pairs) == 0


@pytest.mark.parametrize("bad", [[0, 2 ** 15, 0, 0], [0, 0, -(2 ** 15) - 1, 0], [-1, 0, 0, 0], [2 ** 15, 0, 0, 0]],
                         ids=["i_too_big", "j_too_small", "negative_batch", "batch_too_big"])
def test_unpackable_coordinates_raise_naming_the_range(bad):
    coords = np.asarray([[0, 0, 0, 0], bad], np.int32)
    with pytest.raises(ValueError, match=r"\[-32768, 32767\]"):
        sparse.submanifold_map(coords, np.ones(2, bool))
    # an invalid (padding) row may hold anything
    sparse.submanifold_map(coords, np.asarray([True, False]))


@pytest.mark.parametrize("as_array", [np.asarray, jnp.asarray], ids=["numpy", "jax"])
def test_the_range_check_gives_one_verdict_on_numpy_and_jax_arrays(as_array):
    good = np.asarray([[0, 0, 0, 0], [K.BATCH_MAX, K.COORD_MAX, K.COORD_MIN, 0]], np.int32)
    assert K.check_range(as_array(good), as_array(np.ones(2, bool)), "pack") is not None
    bad = np.asarray([[0, 0, 0, 0], [0, 0, K.COORD_MAX + 1, 0]], np.int32)
    K.check_range(as_array(bad), as_array(np.asarray([True, False])), "pack")     # padding may hold anything
    with pytest.raises(ValueError, match=r"pack: voxel coordinates must lie in \[-32768, 32767\]"):
        K.check_range(as_array(bad), as_array(np.ones(2, bool)), "pack")


def test_unpackable_coordinates_under_jit_raise():
    coords = jnp.asarray([[0, 0, 0, 0], [0, 40000, 0, 0]], jnp.int32)
    with pytest.raises(Exception, match="32767"):
        jax.block_until_ready(jax.jit(lambda c: sparse.submanifold_map(c, jnp.ones(2, bool)).in_idx)(coords))


def test_keys_round_trip_and_order():
    rng = np.random.default_rng(15)
    c = np.concatenate([rng.integers(0, 100, (500, 1)), rng.integers(-2 ** 15, 2 ** 15, (500, 3))], 1).astype(np.int32)
    keys = K.pack(jnp.asarray(c), jnp.ones(500, bool))
    np.testing.assert_array_equal(np.asarray(K.unpack(keys)), c)
    s = K.sort_keys(keys)
    np.testing.assert_array_equal(np.asarray(K.unpack(K.Keys(s.hi, s.lo))), c[np.lexsort(c.T[::-1])])


def test_overflow_is_reported():
    coords, _ = sparse_sites(1.0)
    valid = np.ones(len(coords), bool)
    kmap = sparse.submanifold_map(coords, valid, block=16, n_blocks=4)
    assert bool(kmap.overflowed)
    _, _, overflowed = sparse.downsample(coords, valid, capacity=3)
    assert bool(overflowed)


@pytest.mark.parametrize("step_rows", [4096, 64], ids=["one_step", "steps"])
@pytest.mark.parametrize("kernel_size, centred, stride", [(1, True, 1), (3, True, 1), (5, True, 1), (2, False, 2),
                                                          (3, False, 2)])
def test_neighbour_table_equals_one_lookup_per_offset(kernel_size, centred, stride, step_rows):
    rng = np.random.default_rng(kernel_size * 10 + stride)
    # columns of a few voxels, stacked tightly, at the edges of the packable range too
    coords = np.concatenate([rng.integers(-3, 4, (300, 4)), rng.integers(K.COORD_MAX - 3, K.COORD_MAX + 1, (40, 4)),
                             rng.integers(K.COORD_MIN, K.COORD_MIN + 4, (40, 4))]).astype(np.int32)
    coords[:, 0] = rng.integers(0, 2, len(coords))
    in_coords = np.unique(coords, axis=0)
    in_valid = rng.random(len(in_coords)) < 0.9
    out_coords = np.concatenate([in_coords, np.floor_divide(in_coords, np.asarray([1, stride, stride, stride]))])
    out_coords[:, 0] = np.concatenate([in_coords[:, 0]] * 2)
    out_valid = rng.random(len(out_coords)) < 0.9
    # a run of padding rows: whole steps with no valid row are skipped
    out_coords = np.concatenate([out_coords[:300], in_coords[:200], out_coords[300:]])
    out_valid = np.concatenate([out_valid[:300], np.zeros(200, bool), out_valid[300:]])
    got = np.asarray(neighbour_table(jnp.asarray(in_coords), jnp.asarray(in_valid), jnp.asarray(out_coords),
                                     jnp.asarray(out_valid), kernel_size=kernel_size, centred=centred, stride=stride,
                                     step_rows=step_rows))
    where = {tuple(c): i for i, c in enumerate(in_coords) if in_valid[i]}
    offsets = kernel_offsets(kernel_size, centred=centred)
    want = np.full((len(out_coords), len(offsets)), len(in_coords), np.int32)
    for o, c in enumerate(out_coords):
        if out_valid[o]:
            for d, off in enumerate(offsets):
                q = (c[0], *(stride * c[1:] + off))
                want[o, d] = where.get(q, len(in_coords))
    np.testing.assert_array_equal(got, want)


def test_inner_table_is_the_smaller_kernels_table():
    coords, _ = sparse_sites(0.4, seed=12, shape=(9, 8, 7))
    valid = np.random.default_rng(0).random(len(coords)) < 0.9
    big = neighbour_table(coords, valid, coords, valid, kernel_size=5)
    for k in (1, 3, 5):
        np.testing.assert_array_equal(np.asarray(sparse.inner_table(big, k)),
                                      np.asarray(neighbour_table(coords, valid, coords, valid, kernel_size=k)))
    for bad in (2, 7):
        with pytest.raises(ValueError, match="inner_table"):
            sparse.inner_table(big, bad)


@pytest.mark.parametrize("chunk_rows", [64, 4096])
def test_table_conv_equals_the_pair_list_conv(chunk_rows):
    coords, feats = sparse_sites(0.3, seed=11, shape=(9, 8, 7))
    pad = 200                                                          # padding rows: whole chunks of them
    coords = jnp.asarray(np.concatenate([coords, np.zeros((pad, 4), np.int32)]))
    valid = jnp.arange(len(coords)) < len(feats)
    feats = jnp.asarray(np.concatenate([feats, np.zeros((pad, C_IN), np.float32)]))
    weight = weights(5)
    kmap = sparse.submanifold_map(coords, valid, kernel_size=5)
    table = sparse.NeighbourTable(sparse.neighbour_table(coords, valid, coords, valid, kernel_size=5),
                                  coords, valid, coords, valid)
    want = np.asarray(sparse.sparse_conv(feats, weight, kmap))
    got = jax.jit(lambda f, w: sparse.table_conv(f, w, table, chunk_rows=chunk_rows))(feats, weight)
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-5, atol=1e-5)
    grad = jax.grad(lambda w: jnp.sum(sparse.table_conv(feats, w, table, chunk_rows=chunk_rows) ** 2))(weight)
    ref = jax.grad(lambda w: jnp.sum(sparse.sparse_conv(feats, w, kmap) ** 2))(weight)
    np.testing.assert_allclose(np.asarray(grad), np.asarray(ref), rtol=1e-4, atol=1e-4)
