"""Nearest and harmonic inpainting (brute force / sparse direct solve) and hole filling (scipy)."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference
import scipy.ndimage as ndi
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg
from reference import Case

from gfjax import raster

CASES = [
    Case("random", (32, 24), valid_fraction=0.6),
    Case("sparse", (32, 24), valid_fraction=0.03),
    Case("all_empty", (32, 24), valid_fraction=0.0),
    Case("all_full", (32, 24), valid_fraction=1.0),
    Case("one_row", (1, 33), valid_fraction=0.15),
    Case("one_column", (33, 1), valid_fraction=0.15),
    Case("one_cell", (1, 1), valid_fraction=1.0),
]


def _gap_case():
    """Valid cells with a large rectangular gap and a gap touching the border."""
    z, valid = reference.random_raster(Case("gap", (32, 24), valid_fraction=0.8), seed=7)
    valid[6:26, 4:20] = False
    valid[:, -3:] = False
    return z, valid


@functools.cache
def jitted():
    def fn(z, valid):
        index, dist2 = raster.nearest_valid_index(valid)
        harmonic, iterations, converged = raster.solve_harmonic(z, valid, tol_m=1e-6)
        return index, dist2, raster.inpaint_nearest(z, valid), harmonic, iterations, converged
    return jax.jit(fn)


@pytest.mark.parametrize("case", CASES, ids=str)
def test_nearest_matches_brute_force(case):
    z, valid = reference.random_raster(case, seed=0)
    index, dist2, filled, *_ = jitted()(z, valid)
    want_index, want_dist2 = reference.nearest_index(valid)
    np.testing.assert_array_equal(np.asarray(index), want_index)
    np.testing.assert_array_equal(np.asarray(dist2), want_dist2)
    want = z.ravel()[want_index] if valid.any() else np.zeros_like(z)
    np.testing.assert_array_equal(np.asarray(filled), want.reshape(z.shape))


def test_nearest_distance_matches_scipy_edt():
    z, valid = _gap_case()
    _, dist2, filled, *_ = jitted()(z, valid)
    np.testing.assert_allclose(np.sqrt(np.asarray(dist2)), ndi.distance_transform_edt(~valid), rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(filled)[valid], z[valid])


@pytest.mark.parametrize("case", CASES + [Case("gap", (32, 24))], ids=str)
def test_harmonic_matches_sparse_solve(case):
    z, valid = _gap_case() if case.name == "gap" else reference.random_raster(case, seed=1)
    _, _, _, got, iterations, converged = jitted()(z, valid)
    got = np.asarray(got)
    want = reference.harmonic(z, valid)
    assert bool(converged) and int(iterations) <= 30
    np.testing.assert_array_equal(got[valid], z[valid])
    np.testing.assert_allclose(got, want, atol=1e-4, rtol=0)     # float32, z ~ 100 m


def test_harmonic_stays_within_valid_range():
    """Maximum principle: the harmonic fill never leaves [min, max] of the data."""
    z, valid = _gap_case()
    got = np.asarray(jitted()(z, valid)[3])
    assert got.min() >= z[valid].min() - 1e-4 and got.max() <= z[valid].max() + 1e-4


def test_harmonic_reproduces_a_plane_in_one_direction():
    """A surface linear along columns with full valid rows at top and bottom: exact plane."""
    h, w = 32, 24
    z = np.broadcast_to((np.arange(h, dtype=np.float32) * 0.5)[:, None], (h, w)).copy()
    valid = np.zeros((h, w), bool)
    valid[0], valid[-1] = True, True
    got = np.asarray(jitted()(z, valid)[3])
    np.testing.assert_allclose(got, z, atol=1e-4)


@pytest.mark.parametrize("case", [CASES[1]], ids=str)
def test_jit_equals_eager(case):
    z, valid = reference.random_raster(case, seed=2)
    zj, vj = jnp.asarray(z), jnp.asarray(valid)
    # Harmonic is left out: eager dispatch of its multigrid set-up compiles every small op
    # separately (~20 s); its loop body is compiled in both modes anyway.
    eager = (*raster.nearest_valid_index(vj), raster.inpaint_nearest(zj, vj))
    for got, want in zip(jitted()(z, valid), eager):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_vmap_equals_loop():
    tiles = [reference.random_raster(Case("random", (32, 24), valid_fraction=f), seed=s)
             for s, f in enumerate((0.6, 0.03, 0.0))]
    z, valid = (np.stack(x) for x in zip(*tiles))
    fn = jitted()
    batched = jax.jit(jax.vmap(fn))(z, valid)
    for b in range(len(tiles)):
        for got, want in zip(batched, fn(z[b], valid[b])):
            # harmonic: vmap runs every tile for the most sweeps any needs; both are within the
            # solver's tolerance of the exact solution (test_harmonic_matches_sparse_solve)
            np.testing.assert_allclose(np.asarray(got[b]), np.asarray(want), atol=1e-4, rtol=0)


def test_nearest_padding_never_changes_valid_cells():
    """Empty cells added south and east (a vmap bucket) change no original cell's nearest value."""
    z, valid = reference.random_raster(CASES[1], seed=3)
    zp = np.zeros((40, 40), np.float32)
    vp = np.zeros((40, 40), bool)
    zp[:32, :24], vp[:32, :24] = z, valid
    fn = jax.jit(raster.inpaint_nearest)
    small, big = np.asarray(fn(z, valid)), np.asarray(fn(zp, vp))
    np.testing.assert_array_equal(big[:32, :24], small)


NEED_CASES = [Case("random", (32, 24), valid_fraction=0.6), Case("sparse", (32, 24), valid_fraction=0.03),
              Case("all_empty", (32, 24), valid_fraction=0.0), Case("one_row", (1, 33), valid_fraction=0.15)]


def _padded_with_need(case, seed):
    """A raster in the south-west corner of a larger empty one, `need` = the raster's cells."""
    z, valid = reference.random_raster(case, seed=seed)
    h, w = z.shape
    zp, vp, need = np.zeros((h + 30, w + 40), np.float32), np.zeros((h + 30, w + 40), bool), np.zeros((h + 30, w + 40), bool)
    zp[30:, :w], vp[30:, :w], need[30:, :w] = z, valid, True
    return zp, vp, need


@pytest.mark.parametrize("case", NEED_CASES, ids=str)
def test_nearest_with_need_matches_brute_force_on_needed_cells(case):
    """With `need`, every needed cell still gets its exact nearest valid cell (ties: smallest
    index) and value; the others hold a valid cell's index or -1."""
    zp, vp, need = _padded_with_need(case, seed=4)
    index, dist2 = jax.jit(raster.nearest_valid_index)(vp, need)
    filled = jax.jit(raster.inpaint_nearest)(zp, vp, need)
    want_index, want_dist2 = reference.nearest_index(vp)
    index, dist2, filled = np.asarray(index), np.asarray(dist2), np.asarray(filled)
    np.testing.assert_array_equal(index[need], want_index[need])
    np.testing.assert_array_equal(dist2[need], want_dist2[need])
    want = zp.ravel()[want_index] if vp.any() else np.zeros_like(zp.ravel())
    np.testing.assert_array_equal(filled[need], want.reshape(zp.shape)[need])
    other = index[~need]
    assert np.all((other == -1) | vp.ravel()[np.maximum(other, 0)])


def test_nearest_with_need_under_vmap_equals_each_tile():
    tiles = [_padded_with_need(case, seed) for seed, case in enumerate(NEED_CASES[:3])]
    zp, vp, need = (np.stack(x) for x in zip(*tiles))
    batched = np.asarray(jax.jit(jax.vmap(raster.inpaint_nearest))(zp, vp, need))
    for b in range(len(tiles)):
        alone = np.asarray(jax.jit(raster.inpaint_nearest)(zp[b], vp[b], need[b]))
        np.testing.assert_array_equal(batched[b][need[b]], alone[need[b]])


def test_nearest_with_need_stops_sooner_than_without():
    """The search goes only as far as the needed cells need: data in the first column, needed
    cells in the first four, so a far cell is never reached (no candidate, distance 2^30)."""
    valid = np.zeros((8, 200), bool)
    valid[:, 0] = True
    need = np.zeros((8, 200), bool)
    need[:, :4] = True
    _, with_need = raster.nearest_valid_index(jnp.asarray(valid), jnp.asarray(need))
    _, without = raster.nearest_valid_index(jnp.asarray(valid))
    assert int(np.asarray(without)[0, -1]) == 199 ** 2
    assert int(np.asarray(with_need)[0, -1]) > 199 ** 2


# ---- harmonic fill on a domain (a tile's own cells inside a padded raster) -------------------

DOMAIN_SHAPE = (40, 40)


def _harmonic_on_domain(z: np.ndarray, valid: np.ndarray, domain: np.ndarray) -> np.ndarray:
    """Direct sparse solve of the Laplace equation on the empty cells of the domain, the 5-point
    stencil restricted to the domain (zero flux across its border), valid domain cells as
    Dirichlet data (float64). Outside the domain: `z`; components without data: 0."""
    h, w = z.shape
    fixed = valid & domain
    labels, _ = ndi.label(domain)                               # 4-connectivity
    solved = domain & np.isin(labels, np.unique(labels[fixed]))
    out = np.where(domain, np.where(fixed, z, 0.0), z).astype(np.float64)
    free = np.flatnonzero((solved & ~fixed).ravel())
    if free.size == 0:
        return out
    pos = -np.ones(h * w, np.int64)
    pos[free] = np.arange(free.size)
    a = scipy.sparse.lil_matrix((free.size, free.size))
    rhs = np.zeros(free.size)
    flat = out.ravel()
    for k, i in enumerate(free):
        r, c = divmod(i, w)
        for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= rr < h and 0 <= cc < w and domain[rr, cc]:
                a[k, k] += 1.0
                if pos[rr * w + cc] >= 0:
                    a[k, pos[rr * w + cc]] -= 1.0
                else:
                    rhs[k] += flat[rr * w + cc]
    flat[free] = scipy.sparse.linalg.spsolve(a.tocsc(), rhs)
    return flat.reshape(h, w)


def _domain_case(name: str):
    z, valid = reference.random_raster(Case(name, DOMAIN_SHAPE, valid_fraction=0.08), seed=11)
    h, w = DOMAIN_SHAPE
    if name == "random":            # several components, some without data, ragged borders
        domain = ndi.binary_opening(np.random.default_rng(5).random(DOMAIN_SHAPE) < 0.6)
        domain[:, 19:21] = False                                   # a data-free strip ...
        domain[10:14, 19:21] = True                                # ... joined to the left half
        domain[30:36, 30:36], valid[30:36, 30:36] = True, False   # an island without data
        domain[29, 29:37] = domain[36, 29:37] = False
        domain[29:37, 29] = domain[29:37, 36] = False
    elif name == "L":
        domain = np.ones(DOMAIN_SHAPE, bool)
        domain[: h // 2, w // 2:] = False
    else:                           # "corner": a 32 x 24 tile in the south-west of the raster
        domain = np.zeros(DOMAIN_SHAPE, bool)
        domain[h - 32:, :24] = True
        valid[:, :] = False
        valid[h - 32:, :24] = _gap_case()[1]
        z[h - 32:, :24] = _gap_case()[0]
    z = np.where(domain, z, np.float32(np.inf))                    # never read outside
    valid = valid | ~domain                                        # valid outside: ignored
    return z, valid, domain


DOMAIN_CASES = ["random", "L", "corner"]


@functools.cache
def jitted_on_domain():
    return jax.jit(lambda z, valid, domain: raster.solve_harmonic(z, valid, domain=domain, tol_m=1e-6))


@pytest.mark.parametrize("name", DOMAIN_CASES)
def test_harmonic_on_domain_matches_sparse_solve(name):
    z, valid, domain = _domain_case(name)
    got, iterations, converged = (np.asarray(x) for x in jitted_on_domain()(z, valid, domain))
    want = _harmonic_on_domain(z, valid, domain)
    assert bool(converged) and int(iterations) <= 40
    np.testing.assert_array_equal(got[~domain], z[~domain])        # outside: as given
    np.testing.assert_array_equal(got[valid & domain], z[valid & domain])
    np.testing.assert_allclose(got[domain], want[domain], atol=1e-4, rtol=0)
    if name == "random":                                           # the data-free island
        np.testing.assert_array_equal(got[30:36, 30:36], 0.0)


def test_harmonic_on_padded_domain_equals_unpadded_fill():
    """A tile padded to a larger raster, with `domain` = its cells, fills as the bare tile."""
    z, valid, domain = _domain_case("corner")
    padded = np.asarray(jitted_on_domain()(z, valid, domain)[0])
    bare = np.asarray(jitted()(*_gap_case())[3])
    np.testing.assert_allclose(padded[DOMAIN_SHAPE[0] - 32:, :24], bare, atol=1e-4, rtol=0)


def test_harmonic_on_domain_vmap_equals_loop():
    z, valid, domain = (np.stack(x) for x in zip(*map(_domain_case, DOMAIN_CASES)))
    fn = jitted_on_domain()
    batched = jax.jit(jax.vmap(fn))(z, valid, domain)[0]
    for b in range(len(DOMAIN_CASES)):
        np.testing.assert_allclose(np.asarray(batched[b]), np.asarray(fn(z[b], valid[b], domain[b])[0]),
                                   atol=1e-4, rtol=0)


def test_harmonic_whole_domain_equals_no_domain():
    z, valid = _gap_case()
    got = jax.jit(lambda z, v: raster.inpaint_harmonic(z, v, domain=jnp.ones(v.shape, bool), tol_m=1e-6))(z, valid)
    np.testing.assert_allclose(np.asarray(got), np.asarray(jitted()(z, valid)[3]), atol=1e-4, rtol=0)


def _annulus():
    m = np.zeros((16, 16), bool)
    m[2:12, 2:12] = True
    m[4:10, 4:10] = False
    m[6, 6] = True                                                # an island inside the hole
    m[13:16, 0:5] = True
    m[14, 1:4] = False                                            # a hole in a block on the border
    m[0:3, 12:16] = True
    m[0, 13:15] = False                                           # a notch open to the border: no hole
    return m


HOLE_MASKS = {
    "random": np.random.default_rng(0).random((32, 24)) < 0.6,
    "random_dense": np.random.default_rng(1).random((32, 24)) < 0.75,
    "annulus": _annulus(),
    "diagonal_leak": np.eye(8, dtype=bool) | np.eye(8, dtype=bool)[::-1],
    "all_empty": np.zeros((8, 8), bool),
    "all_full": np.ones((8, 8), bool),
    "one_row": np.random.default_rng(2).random((1, 33)) < 0.5,
}


@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize("name", HOLE_MASKS)
def test_fill_holes_matches_scipy(name, connectivity):
    mask = HOLE_MASKS[name]
    fn = jax.jit(functools.partial(raster.fill_holes, connectivity=connectivity))
    expected = ndi.binary_fill_holes(mask, structure=reference.structure(connectivity))
    np.testing.assert_array_equal(np.asarray(fn(mask)), expected)
    batched = jax.vmap(fn)(np.stack([mask, ~mask]))
    np.testing.assert_array_equal(np.asarray(batched[1]), np.asarray(fn(~mask)))


def test_bad_shapes(unchecked):
    with pytest.raises(ValueError, match="shape"):
        raster.inpaint_nearest(jnp.zeros((3, 3)), jnp.zeros((3, 4), bool))
    with pytest.raises(ValueError, match="shape"):
        raster.inpaint_harmonic(jnp.zeros((3, 3)), jnp.zeros((3, 4), bool))
    with pytest.raises(ValueError, match="domain shape"):
        raster.inpaint_harmonic(jnp.zeros((3, 3)), jnp.zeros((3, 3), bool), domain=jnp.ones((3, 4), bool))


@pytest.mark.parametrize("seed", range(4))
def test_the_coarsest_solve_matches_numpy_on_spd_systems(seed):
    """The V-cycle's coarsest solve (no LAPACK call, so its programs store as executables)
    against `numpy.linalg.solve`: random SPD systems of 1 to 64 unknowns, and a graph
    Laplacian with Dirichlet rows, as the coarsest level builds."""
    from gfjax.raster.harmonic import _spd_solve

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 65))
    q = rng.normal(size=(n, n))
    a = q @ q.T + n * np.eye(n)
    b = rng.normal(size=n)
    got = jax.jit(_spd_solve)(jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32))
    np.testing.assert_allclose(np.asarray(got), np.linalg.solve(a, b), rtol=2e-4, atol=2e-5)
    side = 8
    lap = scipy.sparse.csgraph.laplacian(scipy.sparse.diags([1.0, 1.0], [1, side], shape=(side * side,) * 2),
                                         symmetrized=True).toarray() + np.diag(rng.uniform(0.0, 1.0, side * side) > 0.7)
    lap[0, 0] += 1.0                                            # at least one Dirichlet neighbour
    got = jax.jit(_spd_solve)(jnp.asarray(lap, jnp.float32), jnp.asarray(b[:1].repeat(side * side), jnp.float32))
    np.testing.assert_allclose(np.asarray(got), np.linalg.solve(lap, b[:1].repeat(side * side)), rtol=1e-3, atol=1e-4)
