"""Accuracy smoke tests on two shared ISPRS samples and one BCTS forest tile (skipped when
../shared/data is absent).

The bounds are loose on purpose (the full figures are `experiments/dmf_isprs.md`): they catch a
broken pipeline, not a small regression.
"""
from __future__ import annotations

import pytest

import gfjax
from gfjax import dmf, metrics


@pytest.mark.data
@pytest.mark.parametrize("name,max_total_error", [("samp21", 0.10), ("samp54", 0.12)])
def test_isprs_sample_total_error(isprs_sample, name, max_total_error):
    cloud = gfjax.read(isprs_sample(name))
    result = dmf.filter(cloud)
    m = metrics.point_metrics(result.ground, cloud.classification == 2)
    assert m["total_error"] <= max_total_error, m
    assert result.diagnostics.converged


@pytest.mark.data
@pytest.mark.slow
def test_forest_dtm_meets_the_done_criterion():
    """bcts_1 (forest, W = 1 m): the default's DTM against the vendor ground meets the forest
    bound (RMSE <= 0.3 m, R_O <= 5 %; measured 0.175 m, 0.07 %): a fixed 0.5 m height
    threshold took understory as ground there (bcts_2: 0.343 m)."""
    from conftest import shared_file

    cloud = gfjax.read(shared_file("lasR_bcts/bcts_1.laz"))
    result = dmf.filter(cloud)
    dtm = metrics.dtm_metrics(cloud.xyz_m, result.ground, cloud.classification == 2, cell_m=2.0)
    assert dtm["rmse_m"] <= 0.3 and dtm["r_o"] <= 0.05, dtm
