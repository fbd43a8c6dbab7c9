"""Accuracy smoke test on two shared ISPRS samples (skipped when ../shared/data is absent).

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
