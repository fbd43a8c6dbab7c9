"""Cache attack: the disk fills up (ENOSPC) while an entry is stored. The result is right,
no temporary file or "never store" marker is left, and the next process stores the entry."""
from __future__ import annotations

import errno
import os

import jax
import jax.numpy as jnp
import numpy as np
from cache_attack_helpers import assert_correct, entries, new_process, private, run

from gfjax import aot
from gfjax.aot import store

__all__ = ["private"]


def _disk_full(monkeypatch):
    """Every write through a descriptor `os.fdopen` wraps fails with ENOSPC."""
    real = os.fdopen

    class Full:
        def __init__(self, fd, *a, **k):
            self.file = real(fd, *a, **k)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.file.close()

        def write(self, _):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(store.os, "fdopen", Full)


def test_disk_full_while_storing_leaves_no_marker(private, monkeypatch):
    with monkeypatch.context() as patch:
        _disk_full(patch)
        assert_correct(run())
    assert list(private.iterdir()) == []                    # no temporary, no marker
    new_process()
    assert_correct(run())                                   # disk freed: stored now
    assert len(entries(private)) == 1


@jax.jit
def _solve(a, b):
    return jnp.linalg.solve(a, b)                           # LAPACK custom calls on CPU: exported


def test_disk_full_while_exporting_leaves_no_marker(private, monkeypatch):
    a = np.array([[3.0, 1.0], [1.0, 2.0]], np.float32)
    b = np.array([9.0, 8.0], np.float32)
    with monkeypatch.context() as patch:
        _disk_full(patch)
        out = aot.call(_solve, a, b, tag=("tests.reliability", "solve"))
    np.testing.assert_allclose(out, np.linalg.solve(a, b), rtol=1e-6)
    assert list(private.iterdir()) == []
    new_process()
    np.testing.assert_allclose(aot.call(_solve, a, b, tag=("tests.reliability", "solve")), np.linalg.solve(a, b),
                               rtol=1e-6)
    assert [p.name.endswith(".export.gfjaxexe") for p in private.iterdir()] == [True]
