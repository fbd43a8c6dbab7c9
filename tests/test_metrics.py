"""Point and DTM metrics on hand-computed cases; the soft confusion under jit, vmap, grad."""
from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gfjax import metrics
from gfjax.errors import InputError

T, F = True, False


def _b(*values):
    return np.array(values, dtype=bool)


# (name, pred, ref, expected) -- every expected figure worked out by hand (see comments).
HAND_CASES = [
    # tp = 3 (0, 4, 8), fp = 1 (1), fn = 2 (2, 7), tn = 4; p_e = (4*5 + 6*5) / 100 = 0.5
    ("mixed", _b(T, T, F, F, T, F, F, F, T, F), _b(T, F, T, F, T, F, F, T, T, F),
     dict(tp=3, fp=1, fn=2, tn=4, n_points=10, oa=0.7, total_error=0.3, type1=0.4, type2=0.2,
          kappa=0.4, f1=2 / 3, iou_ground=0.5, iou_nonground=4 / 7)),
    # reference has no ground; one object accepted. p_e = (1*0 + 3*4) / 16 = 0.75 -> kappa 0
    ("no_ground_ref", _b(T, F, F, F), _b(F, F, F, F),
     dict(tp=0, fp=1, fn=0, tn=3, n_points=4, oa=0.75, total_error=0.25, type1=0.0, type2=0.25,
          kappa=0.0, f1=0.0, iou_ground=0.0, iou_nonground=0.75)),
    # no ground anywhere and none predicted: perfect agreement on one class
    ("no_ground_both", _b(F, F, F, F), _b(F, F, F, F),
     dict(tp=0, fp=0, fn=0, tn=4, n_points=4, oa=1.0, total_error=0.0, type1=0.0, type2=0.0,
          kappa=1.0, f1=1.0, iou_ground=1.0, iou_nonground=1.0)),
    # all ground, one rejected. p_e = (2*3 + 1*0) / 9 = 2/3 = p_o -> kappa 0
    ("all_ground_ref", _b(T, T, F), _b(T, T, T),
     dict(tp=2, fp=0, fn=1, tn=0, n_points=3, oa=2 / 3, total_error=1 / 3, type1=1 / 3,
          type2=0.0, kappa=0.0, f1=0.8, iou_ground=2 / 3, iou_nonground=0.0)),
    ("all_ground_both", _b(T, T, T), _b(T, T, T),
     dict(tp=3, fp=0, fn=0, tn=0, n_points=3, oa=1.0, total_error=0.0, type1=0.0, type2=0.0,
          kappa=1.0, f1=1.0, iou_ground=1.0, iou_nonground=1.0)),
    # everything wrong: p_e = (2*2 + 2*2) / 16 = 0.5, p_o = 0 -> kappa -1
    ("all_wrong", _b(T, T, F, F), _b(F, F, T, T),
     dict(tp=0, fp=2, fn=2, tn=0, n_points=4, oa=0.0, total_error=1.0, type1=1.0, type2=1.0,
          kappa=-1.0, f1=0.0, iou_ground=0.0, iou_nonground=0.0)),
    ("empty", _b(), _b(),
     dict(tp=0, fp=0, fn=0, tn=0, n_points=0, oa=1.0, total_error=0.0, type1=0.0, type2=0.0,
          kappa=1.0, f1=1.0, iou_ground=1.0, iou_nonground=1.0)),
]


@pytest.mark.parametrize("name,pred,ref,expected", HAND_CASES, ids=[c[0] for c in HAND_CASES])
def test_point_metrics_hand_computed(name, pred, ref, expected):
    got = metrics.point_metrics(pred, ref)
    assert tuple(got) == metrics.POINT_KEYS
    assert metrics.confusion(pred, ref) == tuple(expected[k] for k in ("tp", "fp", "fn", "tn"))
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, abs=1e-15), key
    for key in ("n_points", "tp", "fp", "fn", "tn"):
        assert type(got[key]) is int
    assert all(math.isfinite(v) for v in got.values())


def test_mask_drops_points():
    pred, ref = HAND_CASES[0][1], HAND_CASES[0][2]
    mask = np.ones(10, dtype=bool)
    mask[[1, 2]] = False                      # drop the fp and one fn
    got = metrics.point_metrics(pred, ref, mask)
    assert (got["tp"], got["fp"], got["fn"], got["tn"]) == (3, 0, 1, 4)
    assert got["total_error"] == pytest.approx(1 / 8)


def _kappa_float_reference(pred, ref):
    """Textbook kappa from marginal proportions, float64."""
    n = pred.size
    p_o = np.mean(pred == ref)
    p_e = np.mean(pred) * np.mean(ref) + np.mean(~pred) * np.mean(~ref)
    assert n > 0 and p_e < 1
    return (p_o - p_e) / (1 - p_e)


@pytest.mark.parametrize("seed", range(5))
def test_random_against_elementwise_reference(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(50, 500))
    ref = rng.random(n) < rng.uniform(0.1, 0.9)
    pred = np.where(rng.random(n) < 0.8, ref, ~ref)
    got = metrics.point_metrics(pred, ref)
    wrong = pred != ref
    assert got["total_error"] == pytest.approx(np.mean(wrong), rel=1e-12)
    assert got["type1"] == pytest.approx(np.mean(~pred[ref]), rel=1e-12)
    assert got["type2"] == pytest.approx(np.mean(pred[~ref]), rel=1e-12)
    assert got["kappa"] == pytest.approx(_kappa_float_reference(pred, ref), rel=1e-12)
    assert got["oa"] + got["total_error"] == pytest.approx(1.0, rel=1e-15)


@pytest.mark.parametrize("bad", [np.array([2, 0, 2], dtype=np.uint8), np.ones((3, 1), dtype=bool),
                                 np.ones(4, dtype=bool)])
def test_bad_labels_rejected(bad):
    with pytest.raises(InputError, match="ref_ground"):
        metrics.point_metrics(np.ones(3, dtype=bool), bad)


# --- DTM metrics -------------------------------------------------------------------------
# Cells of 2 m, (col, row) from the south-west; every figure below worked out by hand.
# x, y offsets are multiples of 2 m so the cells are the ones named.
_DTM_POINTS = [  # x, y, z, pred, ref
    (0.5, 0.5, 10.0, T, T), (1.5, 1.5, 12.0, T, F),      # (0,0): pred 11, ref 10 -> +1
    (2.5, 0.5, 20.0, T, T), (3.5, 1.0, 20.5, F, T),      # (1,0): pred 20, ref 20.25 -> -0.25
    (4.5, 0.5, 5.0, F, T),                               # (2,0): reference only
    (0.5, 2.5, 30.0, T, F),                              # (0,1): prediction only
    (2.5, 2.5, 7.0, T, T), (3.0, 3.0, -1.0, T, F),       # (1,1): pred 3, ref 7 -> -4
    (5.0, 3.0, 1.0, F, F),                               # (2,1): neither
    (1.0, 5.0, 0.0, T, T), (1.0, 5.5, 5.0, T, F),        # (0,2): pred 2.5, ref 0 -> +2.5
]


def _dtm_case(offset=(500_000.0, 5_400_000.0)):
    a = np.array([p[:3] for p in _DTM_POINTS], dtype=np.float64)
    a[:, :2] += np.asarray(offset)
    return a, _b(*(p[3] for p in _DTM_POINTS)), _b(*(p[4] for p in _DTM_POINTS))


def test_dtm_metrics_hand_computed():
    xyz, pred, ref = _dtm_case()
    got = metrics.dtm_metrics(xyz, pred, ref, cell_m=2.0)
    assert tuple(got) == metrics.DTM_KEYS
    diffs = np.array([1.0, -0.25, -4.0, 2.5])
    assert got["n_cells_both"] == 4
    assert got["rmse_m"] == pytest.approx(math.sqrt(23.3125 / 4), rel=1e-12)
    assert got["mean_diff_m"] == pytest.approx(diffs.mean(), rel=1e-12)
    assert got["r_o"] == pytest.approx(1 / 5)
    assert got["r_m"] == pytest.approx(1 / 5)
    for key in ("share_lt_1m", "share_1_2m", "share_2_3m", "share_ge_3m"):
        assert got[key] == pytest.approx(0.25), key


def test_dtm_metrics_identical_and_disjoint():
    xyz, pred, ref = _dtm_case()
    same = metrics.dtm_metrics(xyz, ref, ref)
    assert (same["rmse_m"], same["mean_diff_m"], same["r_o"], same["r_m"]) == (0.0, 0.0, 0.0, 0.0)
    assert same["share_lt_1m"] == 1.0
    none = np.zeros(len(ref), dtype=bool)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        empty_pred = metrics.dtm_metrics(xyz, none, ref)
        nothing = metrics.dtm_metrics(np.zeros((0, 3)), _b(), _b())
    assert empty_pred["r_o"] == 1.0 and empty_pred["r_m"] == 0.0
    assert empty_pred["n_cells_both"] == 0 and math.isnan(empty_pred["rmse_m"])
    assert nothing["n_cells_both"] == 0 and nothing["r_o"] == 0.0


def test_dtm_metrics_bad_cell():
    xyz, pred, ref = _dtm_case()
    with pytest.raises(InputError, match="cell_m"):
        metrics.dtm_metrics(xyz, pred, ref, cell_m=0.0)


def test_mean_over_samples_is_unweighted():
    a = metrics.point_metrics(*HAND_CASES[0][1:3])         # 10 points, total error 0.3
    b = metrics.point_metrics(*HAND_CASES[1][1:3])         # 4 points, total error 0.25
    mean = metrics.mean_over_samples([a, b])
    assert mean["total_error"] == pytest.approx(0.275)     # pooled would be 4/14
    assert mean["n_points"] == 7.0
    with pytest.raises(InputError):
        metrics.mean_over_samples([a, {"oa": 1.0}])
    with pytest.raises(InputError):
        metrics.mean_over_samples([])


# --- soft confusion ----------------------------------------------------------------------
N_SOFT = 32


@pytest.fixture(scope="module")
def soft_fns():
    def te(prob, ref, valid):
        return metrics.expected_total_error(metrics.soft_confusion(prob, ref, valid))

    def kappa(prob, ref, valid):
        return metrics.soft_kappa(metrics.soft_confusion(prob, ref, valid))

    return {"confusion": jax.jit(metrics.soft_confusion), "te": jax.jit(te),
            "kappa": jax.jit(kappa), "te_raw": te, "kappa_raw": kappa}


def _soft_case(seed, kind="mixed"):
    rng = np.random.default_rng(seed)
    ref = {"mixed": rng.random(N_SOFT) < 0.5, "no_ground": np.zeros(N_SOFT, bool),
           "all_ground": np.ones(N_SOFT, bool)}[kind]
    valid = rng.random(N_SOFT) < 0.8
    prob = rng.uniform(0.05, 0.95, N_SOFT).astype(np.float32)
    return jnp.asarray(prob), jnp.asarray(ref), jnp.asarray(valid)


def test_soft_confusion_equals_confusion_on_hard_probabilities(soft_fns):
    prob, ref, valid = _soft_case(0)
    hard = np.asarray(prob) > 0.5
    expected = metrics.point_metrics(hard, np.asarray(ref), np.asarray(valid))
    c = soft_fns["confusion"](jnp.asarray(hard, dtype=jnp.float32), ref, valid)
    assert tuple(float(x) for x in c) == tuple(float(expected[k]) for k in ("tp", "fp", "fn", "tn"))
    got_te = soft_fns["te"](jnp.asarray(hard, dtype=jnp.float32), ref, valid)
    got_kappa = soft_fns["kappa"](jnp.asarray(hard, dtype=jnp.float32), ref, valid)
    np.testing.assert_allclose(float(got_te), expected["total_error"], rtol=1e-6)
    np.testing.assert_allclose(float(got_kappa), expected["kappa"], rtol=1e-5)


def test_soft_confusion_is_expectation(soft_fns):
    """Expected counts = sum of per-point probabilities, checked against numpy float64."""
    prob, ref, valid = _soft_case(1)
    p, r, v = (np.asarray(a, dtype=np.float64) for a in (prob, ref, valid))
    expected = [np.sum(p * r * v), np.sum(p * (1 - r) * v), np.sum((1 - p) * r * v),
                np.sum((1 - p) * (1 - r) * v)]
    got = soft_fns["confusion"](prob, ref, valid)
    np.testing.assert_allclose([float(x) for x in got], expected, rtol=1e-6)
    eager = metrics.soft_confusion(prob, ref, valid)
    np.testing.assert_allclose([float(x) for x in got], [float(x) for x in eager], rtol=1e-6)


def test_soft_confusion_vmap_matches_loop(soft_fns):
    cases = [_soft_case(s, k) for s, k in [(2, "mixed"), (3, "no_ground"), (4, "all_ground")]]
    batched = jax.vmap(soft_fns["te_raw"])(*(jnp.stack(a) for a in zip(*cases)))
    looped = [float(soft_fns["te"](*c)) for c in cases]
    np.testing.assert_allclose(np.asarray(batched), looped, rtol=1e-6)


@pytest.mark.parametrize("kind", ["mixed", "no_ground", "all_ground"])
def test_soft_losses_gradients(soft_fns, kind):
    prob, ref, valid = _soft_case(5, kind)
    for name in ("te_raw", "kappa_raw"):
        f = soft_fns[name]
        check_grads(lambda p, f=f: f(p, ref, valid), (prob,), order=1, modes=["rev"], eps=1e-2,
                    atol=1e-2, rtol=1e-2)
        g = jax.grad(f)(prob, ref, valid)
        assert np.all(np.isfinite(np.asarray(g)))
        assert np.all(np.asarray(g)[~np.asarray(valid)] == 0)
    # expected total error falls when a reference-ground point's probability rises
    g = np.asarray(jax.grad(soft_fns["te_raw"])(prob, ref, valid))
    r, v = np.asarray(ref), np.asarray(valid)
    assert np.all(g[r & v] < 0) and np.all(g[~r & v] > 0)


def test_soft_kappa_degenerate_is_finite(soft_fns):
    ones = jnp.ones(N_SOFT, dtype=jnp.float32)
    ref = jnp.ones(N_SOFT, dtype=bool)
    valid = jnp.ones(N_SOFT, dtype=bool)
    assert float(soft_fns["kappa"](ones, ref, valid)) == 1.0      # p_e = 1, agreement
    g = jax.grad(soft_fns["kappa_raw"])(ones, ref, valid)
    assert np.all(np.isfinite(np.asarray(g)))
    none = jnp.zeros(N_SOFT, dtype=bool)
    assert float(soft_fns["te"](ones, ref, none)) == 0.0         # n = 0
