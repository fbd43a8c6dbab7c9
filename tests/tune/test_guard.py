"""The out-of-sample guard: the sign-flip test against brute force, and `validate`'s rule on
cases where it must keep the fit, must keep the defaults, and must validate by sample."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from gfjax.smrf import tuning as tsmrf
from gfjax.tune import fit as tfit
from gfjax.tune import guard

from .helpers import WINDOWS, problem

SETTINGS = tfit.Settings(steps=6, eval_every=3, windows_m=WINDOWS)
NAMES = ("flat", "roof", "rough")     # one problem (one compile) for every test; weights pick samples
ROUGH_ALONE = np.array([0.0, 0.0, 1.0])
FLAT_ALONE = np.array([1.0, 0.0, 0.0])


def brute_p(e: np.ndarray) -> float:
    e = e[e != 0]
    sums = [np.dot(s, np.abs(e)) for s in itertools.product((-1.0, 1.0), repeat=e.size)]
    return float(np.mean(np.asarray(sums) >= e.sum() - 1e-12))


@pytest.mark.parametrize("seed", range(4))
def test_sign_flip_p_equals_enumeration(seed):
    rng = np.random.default_rng(seed)
    e = rng.normal(0.3, 1.0, 9) * (rng.random(9) > 0.2)
    assert guard.sign_flip_p(e) == pytest.approx(brute_p(e), abs=1e-12)


def test_sign_flip_p_edge_cases_and_sampled_form():
    assert guard.sign_flip_p(np.zeros(5)) == 1.0
    assert guard.sign_flip_p(np.ones(5)) == pytest.approx(1 / 32)          # McNemar's exact tail
    assert guard.sign_flip_p(-np.ones(5)) == 1.0
    assert guard.sign_flip_p(np.array([1.0, -1.0])) == pytest.approx(0.75)
    e = np.random.default_rng(7).normal(0.2, 1.0, 18)                       # > 16 units: sampled
    assert guard.sign_flip_p(e, seed=1) == pytest.approx(brute_p(e), abs=0.015)


def test_guard_keeps_a_fit_that_helps_in_every_block():
    """One sample of positive weight: validated by block; a sample of weight 0 is neither
    trained on nor a unit."""
    pb = problem(NAMES)
    one = np.zeros(3, np.int32)
    hard0 = tfit.hard_errors(pb, tsmrf.TUNER.defaults[None, :], pb.masks(), one, 6.0)[2]
    v = guard.validate(pb, SETTINGS, weight=ROUGH_ALONE, folds=2, block_m=10.0)
    assert not v.by_sample[0] and v.units[0] >= 5
    np.testing.assert_allclose(v.default_error[0], hard0)                  # every point held out once
    assert v.kept[0] and v.p_value[0] < 0.05 and v.tuned_error[0] < v.default_error[0]
    assert v.shrink[0] in guard.SHRINK and v.fit is not None
    expect = tsmrf.TUNER.defaults + v.shrink[0] * (v.fit.values[0] - tsmrf.TUNER.defaults)
    np.testing.assert_allclose(v.values[0], expect, rtol=1e-6)
    assert v.window_m[0] == v.fit.window_m[0]
    after = tfit.hard_errors_at(pb, v.values, v.window_m, pb.masks(), one)[2]
    assert after < hard0


def test_guard_keeps_defaults_when_nothing_can_be_gained():
    pb = problem(NAMES)                      # flat: all ground, the defaults label it without error
    v = guard.validate(pb, SETTINGS, weight=FLAT_ALONE, folds=2, block_m=10.0)
    assert not v.kept[0] and v.fit is None and v.p_value[0] == 1.0
    np.testing.assert_array_equal(v.values[0], tsmrf.TUNER.defaults)
    assert v.window_m[0] == 18.0 and v.shrink[0] == 0.0
    assert v.fold_errors.shape == (2, 1, 2)


def test_guard_validates_a_shared_fit_by_sample():
    """Three samples in one group: units are the samples, so at most 3 units, and no p-value
    reaches 0.05 (>= 3 levels x 1/8)."""
    pb = problem(NAMES)
    v = guard.validate(pb, SETTINGS, folds=2, block_m=10.0)
    assert v.by_sample[0] and v.units[0] <= 3 and not v.kept[0] and v.p_value[0] >= 3 / 8
    np.testing.assert_array_equal(v.values[0], tsmrf.TUNER.defaults)


def test_guard_argument_checks():
    pb = problem(NAMES)
    for bad in (dict(shrink=()), dict(shrink=(0.0,)), dict(shrink=(1.5,)), dict(alpha=0.0), dict(alpha=1.0)):
        with pytest.raises(ValueError):
            guard.validate(pb, SETTINGS, **bad)
