"""Context compression (Eqs. 1-3) against the paper's geometric construction (Appendix A)."""
from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gfjax.sparsegf import CENTRAL_TOL_M, R_IN_M, R_OC_M, R_OO_M, compress, compression_ratio

N = 64   # every case has N points, so each jitted function compiles once

# shape errors: our ValueError, or jaxtyping's TypeCheckError (a TypeError) when runtime
# type checking is enabled on gfjax
SHAPE_ERRORS = (ValueError, TypeError)


def geometric_reference(xy, center, *, r_in, r_oc, r_oo):
    """Appendix A, Eqs. 8-14, step by step in float64: p_s on the inner circle along the ray
    from the centre, D'_si = D_si (R_oc - R_in) / (R_oo - R_in), p' = p_s + D'_si along the ray."""
    out = np.array(xy, dtype=np.float64)
    for i, (x, y) in enumerate(out):
        d_ci = math.hypot(x - center[0], y - center[1])                      # Eq. 14
        if d_ci <= r_in:
            continue                                                          # invariant zone
        cos_t, sin_t = (x - center[0]) / d_ci, (y - center[1]) / d_ci         # Eq. 13, theta
        xs, ys = r_in * cos_t + center[0], r_in * sin_t + center[1]          # Eq. 12
        d_si = math.hypot(x - xs, y - ys)
        d_si_c = d_si * (r_oc - r_in) / (r_oo - r_in)                         # Eq. 9
        out[i] = (xs + d_si_c * cos_t, ys + d_si_c * sin_t)                   # Eqs. 8, 10
    return out


def closed_form_reference(xy, center, *, r_in, r_oc, r_oo):
    """Eqs. 1-2 (= Eqs. 15-16) written literally, float64."""
    xy = np.asarray(xy, dtype=np.float64)
    k = (r_oc - r_in) / (r_oo - r_in)
    d = xy - center
    r = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        mapped = k * xy + (1 - k) * (r_in * d / r[:, None] + center)
    return np.where((r > r_in)[:, None], mapped, xy)


def random_patch(seed, *, center=(0.0, 0.0), z_range=(-5.0, 60.0)):
    """N points spread over the whole cylinder, plus the special radii 0, R_in, R_oo."""
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.uniform(0, R_OO_M ** 2, N))
    r[:4] = (0.0, R_IN_M, R_OO_M, R_IN_M + 1e-3)
    theta = rng.uniform(-np.pi, np.pi, N)
    theta[:4] = (0.3, 0.0, np.pi / 2, 2.0)
    xy = np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1) + np.asarray(center)
    xy[1] = (center[0] + R_IN_M, center[1])                         # exactly on the inner circle
    xy[2] = (center[0], center[1] + R_OO_M)                         # exactly on the outer circle
    z = rng.uniform(*z_range, N)
    return np.concatenate([xy, z[:, None]], axis=1).astype(np.float32), np.asarray(center, np.float32)


CASES = {"origin": dict(seed=0), "offset_center": dict(seed=1, center=(812.5, -401.25)),
         "negative_z": dict(seed=2, z_range=(-300.0, -250.0))}
RADII = [dict(r_in=R_IN_M, r_oc=R_OC_M, r_oo=R_OO_M), dict(r_in=10.0, r_oc=20.0, r_oo=150.0)]


@pytest.mark.parametrize("radii", RADII, ids=["paper", "other"])
@pytest.mark.parametrize("case", CASES, ids=str)
def test_matches_geometric_construction(case, radii):
    xyz, center = random_patch(**CASES[case])
    out = compress(jnp.asarray(xyz), jnp.asarray(center), **radii)
    geo = geometric_reference(xyz[:, :2], center.astype(np.float64), **radii)
    closed = closed_form_reference(xyz[:, :2], center.astype(np.float64), **radii)
    np.testing.assert_allclose(closed, geo, rtol=0, atol=1e-9)          # Eqs. 1-2 == Appendix A
    np.testing.assert_allclose(np.asarray(out.xyz[:, :2]), geo, rtol=1e-6, atol=2e-5)
    np.testing.assert_array_equal(np.asarray(out.xyz[:, 2]), xyz[:, 2])   # Eq. 3


@pytest.mark.parametrize("case", CASES, ids=str)
def test_central_unchanged_and_outer_boundary(case):
    xyz, center = random_patch(**CASES[case])
    out = compress(jnp.asarray(xyz), jnp.asarray(center))
    r = np.hypot(*(xyz[:, :2].astype(np.float64) - center).T)
    inner = r <= R_IN_M - 1e-3
    np.testing.assert_array_equal(np.asarray(out.xyz)[inner], xyz[inner])
    np.testing.assert_array_equal(np.asarray(out.xyz)[0], xyz[0])          # r = 0
    np.testing.assert_array_equal(np.asarray(out.xyz)[1], xyz[1])          # r = R_in
    r_out = np.hypot(*(np.asarray(out.xyz[:, :2], np.float64) - center).T)
    np.testing.assert_allclose(r_out[2], R_OC_M, rtol=1e-6)                # R_oo -> R_oc
    assert np.all(r_out <= R_OC_M + 1e-4)
    expected_central = r <= R_IN_M + CENTRAL_TOL_M
    np.testing.assert_array_equal(np.asarray(out.central), expected_central)


def test_radius_monotone_and_direction_preserved():
    center = np.array([3.0, -7.0], np.float32)
    r = np.linspace(0.0, R_OO_M, N)
    for theta in (0.0, 1.0, -2.5, np.pi):
        u = np.array([np.cos(theta), np.sin(theta)])
        xy = center + r[:, None] * u
        xyz = np.concatenate([xy, np.full((N, 1), 12.0)], axis=1).astype(np.float32)
        out = np.asarray(compress(jnp.asarray(xyz), jnp.asarray(center)).xyz, np.float64)
        d = out[:, :2] - center
        r_out = np.hypot(d[:, 0], d[:, 1])
        assert np.all(np.diff(r_out) > 0), "radius must increase strictly along a ray"
        np.testing.assert_allclose(d[1:] / r_out[1:, None], np.broadcast_to(u, (N - 1, 2)), atol=1e-5)
        k = compression_ratio(r_in=R_IN_M, r_oc=R_OC_M, r_oo=R_OO_M)
        r_expected = np.where(r <= R_IN_M, r, R_IN_M + k * (r - R_IN_M))
        np.testing.assert_allclose(r_out, r_expected, rtol=1e-6, atol=2e-5)


def test_commutes_with_rotation_and_translation():
    # training rotates patches about z (Sec. 3.3): compressing then rotating = rotating then compressing
    xyz, center = random_patch(4)
    angle = 0.7
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    shift = np.array([123.25, -45.5])

    def move(p, c):
        p = np.asarray(p, np.float64).copy()
        p[:, :2] = (p[:, :2] - c) @ rot.T + c + shift
        return p

    moved = compress(jnp.asarray(move(xyz, center).astype(np.float32)), jnp.asarray((center + shift).astype(np.float32)))
    expected = move(np.asarray(compress(jnp.asarray(xyz), jnp.asarray(center)).xyz), center)
    np.testing.assert_allclose(np.asarray(moved.xyz), expected, rtol=1e-6, atol=1e-4)


def test_valid_mask_and_padding():
    xyz, center = random_patch(0)
    valid = np.arange(N) < N - 10
    out = compress(jnp.asarray(xyz), jnp.asarray(center), valid=jnp.asarray(valid))
    full = compress(jnp.asarray(xyz), jnp.asarray(center))
    np.testing.assert_array_equal(np.asarray(out.central), np.asarray(full.central) & valid)
    np.testing.assert_array_equal(np.asarray(out.xyz), np.asarray(full.xyz))


def test_jit_matches_eager():
    xyz, center = random_patch(1, center=(812.5, -401.25))
    eager = compress(jnp.asarray(xyz), jnp.asarray(center))
    jitted = jax.jit(functools.partial(compress, r_oc=R_OC_M))(jnp.asarray(xyz), jnp.asarray(center))
    np.testing.assert_array_equal(np.asarray(jitted.xyz), np.asarray(eager.xyz))
    np.testing.assert_array_equal(np.asarray(jitted.central), np.asarray(eager.central))


def test_vmap_matches_loop():
    patches = [random_patch(seed, center=(10.0 * seed, -3.0 * seed)) for seed in range(3)]
    xyz = jnp.asarray(np.stack([p[0] for p in patches]))
    centers = jnp.asarray(np.stack([p[1] for p in patches]))
    valid = jnp.asarray(np.arange(N)[None, :] < np.array([N, N - 5, 7])[:, None])
    batched = jax.vmap(lambda p, c, v: compress(p, c, valid=v))(xyz, centers, valid)
    for b in range(3):
        one = compress(xyz[b], centers[b], valid=valid[b])
        np.testing.assert_array_equal(np.asarray(batched.xyz[b]), np.asarray(one.xyz))
        np.testing.assert_array_equal(np.asarray(batched.central[b]), np.asarray(one.central))


def test_gradients_finite_at_centre_and_inner_circle():
    xyz, center = random_patch(0)

    def total(p, c):
        return jnp.sum(compress(p, c).xyz ** 2)

    g_xyz, g_c = jax.grad(total, argnums=(0, 1))(jnp.asarray(xyz), jnp.asarray(center))
    assert np.all(np.isfinite(np.asarray(g_xyz))) and np.all(np.isfinite(np.asarray(g_c)))
    np.testing.assert_array_equal(np.asarray(g_xyz[:2]), 2 * xyz[:2])   # identity at r = 0, R_in
    jac = jax.jacfwd(lambda p: compress(p, jnp.asarray(center)).xyz)(jnp.asarray(xyz))
    assert np.all(np.isfinite(np.asarray(jac)))


def test_check_grads_away_from_the_kink():
    xyz, center = random_patch(3)
    r = np.hypot(*(xyz[:, :2] - center).T)
    away = np.abs(r - R_IN_M) > 1.0                 # the map has a kink on r = R_in
    xyz = np.where(away[:, None], xyz, xyz * 0.5)
    f = lambda p: compress(jnp.asarray(p), jnp.asarray(center)).xyz           # noqa: E731
    check_grads(f, (jnp.asarray(xyz),), order=1, modes=("fwd", "rev"), eps=1e-2, atol=5e-2, rtol=5e-2)


@pytest.mark.parametrize("radii", [dict(r_in=0.0, r_oc=44.0, r_oo=150.0), dict(r_in=40.0, r_oc=30.0, r_oo=150.0),
                                   dict(r_in=10.0, r_oc=200.0, r_oo=150.0)])
def test_bad_radii_raise(radii):
    xyz, center = random_patch(0)
    with pytest.raises(ValueError, match="r_in"):
        compress(jnp.asarray(xyz), jnp.asarray(center), **radii)


def test_bad_shapes_raise():
    with pytest.raises(SHAPE_ERRORS, match="xyz"):
        compress(jnp.zeros((5, 2), jnp.float32), jnp.zeros(2, jnp.float32))
    with pytest.raises(SHAPE_ERRORS, match="center"):
        compress(jnp.zeros((5, 3), jnp.float32), jnp.zeros(3, jnp.float32))
