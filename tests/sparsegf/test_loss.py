"""Height-aware loss (Eqs. 4-5): hand-computed values, a numpy reference, padding, gradients."""
from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gfjax.sparsegf import HAG_WEIGHTS, height_aware_loss

N = 16

# shape errors: our ValueError, or jaxtyping's TypeCheckError (a TypeError) when runtime
# type checking is enabled on gfjax
SHAPE_ERRORS = (ValueError, TypeError)


def numpy_reference(logits_cls, logits_hag, labels, bins, mask, weights=HAG_WEIGHTS, lam=0.5):
    """Eqs. 4-5 point by point in float64."""
    def log_softmax(z):
        z = np.asarray(z, np.float64)
        return z - z.max() - np.log(np.sum(np.exp(z - z.max())))
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        return 0.0, 0.0, 0.0
    l_cls = -np.mean([log_softmax(logits_cls[i])[labels[i]] for i in idx])
    l_hag = -np.sum([weights[bins[i]] * log_softmax(logits_hag[i])[bins[i]] for i in idx]) / len(idx)
    return (1 - lam) * l_cls + lam * l_hag, l_cls, l_hag


def random_case(seed, *, ground_share=0.5, central_share=0.7):
    rng = np.random.default_rng(seed)
    labels = (rng.random(N) < ground_share).astype(np.int32)
    bins = np.where(labels == 1, 0, rng.integers(1, 6, N)).astype(np.int32)
    return dict(logits_cls=rng.normal(0, 2, (N, 2)).astype(np.float32),
                logits_hag=rng.normal(0, 2, (N, 6)).astype(np.float32),
                labels=labels, hag_bins=bins, central_mask=rng.random(N) < central_share)


def as_jax(case):
    return {k: jnp.asarray(v) for k, v in case.items()}


CASES = {"mixed": dict(seed=0), "all_ground": dict(seed=1, ground_share=1.0),
         "no_ground": dict(seed=2, ground_share=0.0), "all_central": dict(seed=3, central_share=1.0),
         "no_central": dict(seed=4, central_share=0.0)}


@pytest.fixture(scope="module")
def loss_jit():
    return jax.jit(height_aware_loss)


def test_hand_computed_uniform_logits():
    # zero logits: CE_cls = log 2 per point; CE_hag = log 6 per point times w of its bin
    bins = np.array([0, 5, 2, 4], np.int32)
    mask = np.array([True, True, True, False])
    out = height_aware_loss(jnp.zeros((4, 2)), jnp.zeros((4, 6)), jnp.array([1, 0, 0, 0]), jnp.asarray(bins),
                            jnp.asarray(mask))
    l_hag = (1 + 6 + 3) / 3 * math.log(6)
    np.testing.assert_allclose(float(out.cls), math.log(2), rtol=1e-6)
    np.testing.assert_allclose(float(out.hag), l_hag, rtol=1e-6)
    np.testing.assert_allclose(float(out.total), 0.5 * math.log(2) + 0.5 * l_hag, rtol=1e-6)
    assert float(out.n_central) == 3


def test_hand_computed_one_point():
    # one ground point, cls logits (0, ln 3): p(ground) = 3/4; hag logits favour bin 0 by ln 5
    logits_hag = jnp.array([[math.log(5.0), 0, 0, 0, 0, 0]])
    out = height_aware_loss(jnp.array([[0.0, math.log(3.0)]]), logits_hag, jnp.array([1]), jnp.array([0]),
                            jnp.array([True]), lam=0.25)
    np.testing.assert_allclose(float(out.cls), -math.log(3 / 4), rtol=1e-6)
    np.testing.assert_allclose(float(out.hag), -1.0 * math.log(5 / 10), rtol=1e-6)     # w_0 = 1
    np.testing.assert_allclose(float(out.total), 0.75 * -math.log(3 / 4) + 0.25 * math.log(2), rtol=1e-6)


@pytest.mark.parametrize("name", CASES, ids=str)
def test_matches_numpy_reference_under_jit(name, loss_jit):
    case = random_case(**CASES[name])
    out = loss_jit(**as_jax(case))
    eager = height_aware_loss(**as_jax(case))
    total, l_cls, l_hag = numpy_reference(*case.values())
    np.testing.assert_allclose([float(out.total), float(out.cls), float(out.hag)], [total, l_cls, l_hag],
                               rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(np.asarray(out.total), np.asarray(eager.total))
    assert all(np.isfinite(float(v)) for v in out)


@pytest.mark.parametrize("name", CASES, ids=str)
def test_gradients_finite(name):
    case = as_jax(random_case(**CASES[name]))
    grads = jax.grad(lambda c, h: height_aware_loss(c, h, *list(case.values())[2:]).total,
                     argnums=(0, 1))(case["logits_cls"], case["logits_hag"])
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g)))
        np.testing.assert_array_equal(np.asarray(g)[~np.asarray(case["central_mask"])], 0.0)


def test_no_central_points_gives_zero():
    out = height_aware_loss(**as_jax(random_case(**CASES["no_central"])))
    assert float(out.total) == 0.0 and float(out.n_central) == 0.0


def test_invariant_to_padding():
    case = random_case(0)
    pad = 7
    padded = dict(logits_cls=np.r_[case["logits_cls"], np.full((pad, 2), np.nan, np.float32)],
                  logits_hag=np.r_[case["logits_hag"], np.full((pad, 6), 1e30, np.float32)],
                  labels=np.r_[case["labels"], np.full(pad, -1, np.int32)],
                  hag_bins=np.r_[case["hag_bins"], np.full(pad, 99, np.int32)],
                  central_mask=np.r_[case["central_mask"], np.zeros(pad, bool)])
    a, b = height_aware_loss(**as_jax(case)), height_aware_loss(**as_jax(padded))
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)
    padded = as_jax(padded)
    grad = jax.grad(lambda h: height_aware_loss(padded["logits_cls"], h, *list(padded.values())[2:]).total)
    g = np.asarray(grad(padded["logits_hag"]))
    assert np.all(np.isfinite(g)) and np.all(g[N:] == 0)


def test_vmap_over_patches_and_batch_normalisation():
    cases = [random_case(s) for s in range(3)]
    stacked = {k: jnp.asarray(np.stack([c[k] for c in cases])) for k in cases[0]}
    per_patch = jax.vmap(height_aware_loss)(**stacked)
    for b, case in enumerate(cases):
        one = height_aware_loss(**as_jax(case))
        np.testing.assert_allclose(float(per_patch.total[b]), float(one.total), rtol=1e-6)
    # the whole batch at once divides by all of its central points (a concatenated batch)
    whole = height_aware_loss(**stacked)
    n = np.asarray(per_patch.n_central)
    np.testing.assert_allclose(float(whole.total), np.sum(np.asarray(per_patch.total) * n) / n.sum(), rtol=1e-6)


@pytest.mark.parametrize("lam", [0.0, 1.0])
def test_lambda_selects_a_term(lam):
    out = height_aware_loss(**as_jax(random_case(0)), lam=lam)
    np.testing.assert_allclose(float(out.total), float(out.hag if lam == 1.0 else out.cls), rtol=1e-6)


def test_weights_enter_per_point_normalised_by_n():
    # Eq. 4: doubling every weight doubles L_hag (a weighted mean would not change)
    case = as_jax(random_case(0))
    one = height_aware_loss(**case)
    two = height_aware_loss(**case, weights=tuple(2 * w for w in HAG_WEIGHTS))
    np.testing.assert_allclose(float(two.hag), 2 * float(one.hag), rtol=1e-6)


def test_check_grads():
    case = as_jax(random_case(0))
    rest = list(case.values())[2:]
    check_grads(lambda c, h: height_aware_loss(c, h, *rest).total, (case["logits_cls"], case["logits_hag"]),
                order=2, modes=("rev",), eps=1e-2, atol=1e-2, rtol=1e-2)


def test_bad_shapes_and_lambda_raise():
    case = as_jax(random_case(0))
    with pytest.raises(SHAPE_ERRORS, match="logits_hag"):
        height_aware_loss(**{**case, "logits_hag": case["logits_hag"][:, :5]})
    with pytest.raises(SHAPE_ERRORS, match="logits_cls"):
        height_aware_loss(**{**case, "logits_cls": case["logits_cls"][:, :1]})
    with pytest.raises(SHAPE_ERRORS, match="labels"):
        height_aware_loss(**{**case, "labels": case["labels"][:3]})
    with pytest.raises(ValueError, match="lam"):
        height_aware_loss(**case, lam=1.5)
