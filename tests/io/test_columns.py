"""Column-by-column reductions equal numpy's axis reductions, dtype included."""
from __future__ import annotations

import numpy as np
import pytest

from gfjax.io import columns


@pytest.mark.parametrize("shape", [(1, 1), (1, 3), (7, 2), (1000, 3)])
@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int64])
def test_lows_and_highs_equal_numpy(shape, dtype):
    a = (np.random.default_rng(0).normal(size=shape) * 1000).astype(dtype)
    for got, expected in ((columns.lows(a), a.min(axis=0)), (columns.highs(a), a.max(axis=0))):
        np.testing.assert_array_equal(got, expected)
        assert got.dtype == expected.dtype


@pytest.mark.parametrize("shape", [(1, 1), (5, 2), (1000, 3)])
def test_every_and_some_equal_numpy(shape):
    flags = np.random.default_rng(1).random(shape) < 0.6
    np.testing.assert_array_equal(columns.every(flags), np.all(flags, axis=1))
    np.testing.assert_array_equal(columns.some(flags), np.any(flags, axis=1))


def test_every_leaves_its_input_as_it_is():
    flags = np.array([[True, False], [True, True]])
    columns.every(flags), columns.some(flags)
    np.testing.assert_array_equal(flags, [[True, False], [True, True]])


def test_nan_propagates_as_in_numpy():
    a = np.array([[1.0, np.nan], [0.0, 2.0]])
    np.testing.assert_array_equal(columns.lows(a), a.min(axis=0))
    np.testing.assert_array_equal(columns.highs(a), a.max(axis=0))
