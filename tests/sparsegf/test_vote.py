"""Soft voting (Algorithm 1) against a literal Python loop; order, ties, uncovered points."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax.errors import SettingError
from gfjax.sparsegf import UNCOVERED, Config, decide, soft_vote

N_POINTS = 40
SHAPE = (5, 24)   # 5 patches x 24 padded slots

# shape errors: our ValueError, or jaxtyping's TypeCheckError (a TypeError) when runtime
# type checking is enabled on gfjax
SHAPE_ERRORS = (ValueError, TypeError)


def algorithm_1(index, prob, n_points, mask):
    """Algorithm 1 of the paper, literally (float64)."""
    d, c = np.zeros(n_points), np.zeros(n_points, np.int64)
    for i, p, m in zip(index.ravel(), prob.ravel(), mask.ravel()):
        if m and 0 <= i < n_points:
            d[i] += p
            c[i] += 1
    mean = np.where(c > 0, d / np.maximum(c, 1), 0.0)
    label = np.where(c > 0, (mean > 0.5).astype(int), UNCOVERED)
    return mean, c, label


def random_votes(seed):
    """Dyadic probabilities (k / 64): every sum is exact, so any order gives identical bits."""
    rng = np.random.default_rng(seed)
    index = rng.integers(-1, N_POINTS - 5, SHAPE).astype(np.int32)     # -1 padding; last 5 never voted
    prob = (rng.integers(0, 65, SHAPE) / 64.0).astype(np.float32)
    mask = rng.random(SHAPE) < 0.8
    return index, prob, mask


@pytest.fixture(scope="module")
def vote_jit():
    return jax.jit(soft_vote, static_argnames="n_points")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_algorithm_1(seed, vote_jit):
    index, prob, mask = random_votes(seed)
    out = vote_jit(jnp.asarray(index), jnp.asarray(prob), n_points=N_POINTS, mask=jnp.asarray(mask))
    mean, count, label = algorithm_1(index, prob, N_POINTS, mask)
    np.testing.assert_allclose(np.asarray(out.prob_ground), mean, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(out.count), count)
    np.testing.assert_array_equal(np.asarray(out.label), label)
    assert np.all(np.asarray(out.label)[-5:] == UNCOVERED) and np.all(np.asarray(out.count)[-5:] == 0)
    eager = soft_vote(jnp.asarray(index), jnp.asarray(prob), N_POINTS, mask=jnp.asarray(mask))
    for a, b in zip(out, eager):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_order_independent():
    index, prob, mask = random_votes(3)
    perm = np.random.default_rng(9).permutation(index.size)
    a = soft_vote(jnp.asarray(index), jnp.asarray(prob), N_POINTS, mask=jnp.asarray(mask))
    b = soft_vote(jnp.asarray(index.ravel()[perm].reshape(SHAPE)), jnp.asarray(prob.ravel()[perm].reshape(SHAPE)),
                  N_POINTS, mask=jnp.asarray(mask.ravel()[perm].reshape(SHAPE)))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_exact_ties_are_not_ground():
    index = jnp.array([0, 1, 1, 2, 2, 2, 3, 3], jnp.int32)
    prob = jnp.array([0.5, 0.25, 0.75, 0.25, 0.75, 0.5 + 2.0 ** -10, 0.5 + 2.0 ** -10, 0.5], jnp.float32)
    out = soft_vote(index, prob, 5)
    np.testing.assert_array_equal(np.asarray(out.prob_ground)[:2], [0.5, 0.5])
    np.testing.assert_array_equal(np.asarray(out.label), [0, 0, 1, 1, UNCOVERED])
    np.testing.assert_array_equal(np.asarray(out.count), [1, 2, 3, 2, 0])


def test_masked_and_out_of_range_votes_are_ignored():
    index = jnp.array([0, 0, 1, -1, 7, 2], jnp.int32)
    prob = jnp.array([0.9, 0.0, 0.8, 1.0, 1.0, 0.2], jnp.float32)
    mask = jnp.array([True, False, True, True, True, True])
    out = soft_vote(index, prob, 3, mask=mask)
    np.testing.assert_allclose(np.asarray(out.prob_ground), [0.9, 0.8, 0.2], rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(out.count), [1, 1, 1])
    np.testing.assert_array_equal(np.asarray(out.label), [1, 1, 0])


def test_vmap_matches_loop():
    votes = [random_votes(s) for s in range(3)]
    index, prob, mask = (jnp.asarray(np.stack(v)) for v in zip(*votes))
    batched = jax.vmap(lambda i, p, m: soft_vote(i, p, N_POINTS, mask=m))(index, prob, mask)
    for b in range(3):
        one = soft_vote(index[b], prob[b], N_POINTS, mask=mask[b])
        for x, y in zip(batched, one):
            np.testing.assert_array_equal(np.asarray(x[b]), np.asarray(y))


def test_bad_input_raises():
    with pytest.raises(SHAPE_ERRORS, match="same shape|prob_ground"):
        soft_vote(jnp.zeros(3, jnp.int32), jnp.zeros(4, jnp.float32), 3)
    with pytest.raises(SHAPE_ERRORS, match="mask"):
        soft_vote(jnp.zeros(3, jnp.int32), jnp.zeros(3, jnp.float32), 3, mask=jnp.zeros(2, bool))
    with pytest.raises(ValueError, match="n_points"):
        soft_vote(jnp.zeros(3, jnp.int32), jnp.zeros(3, jnp.float32), -1)


def decide_loop(prob, smrf_ground, config):
    """`decide` written out point by point."""
    out = np.zeros(len(prob), bool)
    for i, p in enumerate(prob):
        if config.decision == "network":
            out[i] = p > config.ground_probability
        else:
            out[i] = p > (config.smrf_ground_probability if smrf_ground[i] else config.smrf_object_probability)
    return out


DECISIONS = {
    "paper": Config(decision="network"),
    "with smrf (defaults)": Config(),
    "with smrf, other thresholds": Config(smrf_ground_probability=0.6, smrf_object_probability=0.2),
}


@pytest.mark.parametrize("name", DECISIONS)
def test_decide_matches_a_loop_under_jit_and_vmap(name):
    config = DECISIONS[name]
    rng = np.random.default_rng(3)
    prob = rng.uniform(0, 1, (4, 50)).astype(np.float32)
    prob[:, :7] = [0.0, 0.3, 0.5, 0.8, 0.9, 1.0, 0.2]                  # the thresholds themselves: not ground
    verdict = rng.uniform(size=(4, 50)) < 0.5
    want = np.stack([decide_loop(p, v, config) for p, v in zip(prob, verdict)])
    np.testing.assert_array_equal(np.asarray(decide(prob[0], verdict[0], config=config)), want[0])
    jitted = jax.jit(decide, static_argnames="config")
    np.testing.assert_array_equal(np.asarray(jitted(prob[1], verdict[1], config=config)), want[1])
    batched = jax.vmap(lambda p, v: decide(p, v, config=config))(prob, verdict)
    np.testing.assert_array_equal(np.asarray(batched), want)


@pytest.mark.parametrize("name", DECISIONS)
def test_decide_on_numpy_votes_gives_the_labels_of_jax(name):
    config = DECISIONS[name]
    edges = np.array([0.3, 0.5, 0.9, 0.6, 0.2], np.float32)
    prob = np.concatenate([edges, np.nextafter(edges, np.float32(0)), np.nextafter(edges, np.float32(1)),
                           np.random.default_rng(5).uniform(0, 1, 85).astype(np.float32)])
    verdict = np.arange(len(prob)) % 2 == 0
    on_host = decide(prob, verdict, config=config)
    assert isinstance(on_host, np.ndarray)
    np.testing.assert_array_equal(on_host, np.asarray(decide(jnp.asarray(prob), jnp.asarray(verdict), config=config)))


def test_decide_with_smrf_changes_labels_only_against_the_network_when_confident():
    keep = Config().smrf_ground_probability           # SMRF's ground stays ground above it
    prob = np.array([0.35, 0.35, 0.75, 0.75, 0.95, keep + 0.05, keep - 0.01], np.float32)
    verdict = np.array([True, False, True, False, False, True, True])
    np.testing.assert_array_equal(np.asarray(decide(prob, verdict, config=Config())),
                                  [True, False, True, False, True, True, False])


def test_decide_refuses_a_missing_or_misshapen_verdict():
    prob = np.full(5, 0.5, np.float32)
    with pytest.raises(ValueError, match="needs SMRF's verdict"):
        decide(prob, config=Config())
    with pytest.raises(SHAPE_ERRORS):
        decide(prob, np.ones(4, bool), config=Config())
    assert not np.any(np.asarray(decide(prob, config=Config(decision="network"))))


def test_config_refuses_an_unknown_decision():
    with pytest.raises(SettingError, match="decision must be one of"):
        Config(decision="smrf")
