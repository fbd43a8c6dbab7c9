"""Strict JAX settings for every test, and the path to the shared labelled data."""
from __future__ import annotations

import os
from pathlib import Path

import jax
import pytest

jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_enable_x64", False)

SHARED_DATA = Path(os.environ.get("GFJAX_SHARED_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data")).resolve()
ISPRS = SHARED_DATA / "isprs_filtertest" / "reference"


def shared_file(relative: str) -> Path:
    """A file of `../shared/data`, or skip the test with a clear message when absent."""
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"shared data not found: {path} (set GFJAX_SHARED_DATA)")
    return path


@pytest.fixture
def isprs_sample():
    return lambda name: shared_file(f"isprs_filtertest/reference/{name}-utm.laz")
