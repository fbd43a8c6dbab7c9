"""Shared pieces of the cache attack tests: a small program, a private cache folder, and
guards that fail a test if a stored artifact is unpickled or loaded."""
from __future__ import annotations

import functools
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax import aot
from gfjax.aot import calls, store
from gfjax.aot import folder as aot_folder

SUFFIX = ".gfjaxexe"


class Pair(NamedTuple):
    scaled: jax.Array
    total: jax.Array


@functools.partial(jax.jit, static_argnames=("factor",))
def scale_and_sum(x, mask, *, factor: int = 2) -> Pair:
    return Pair(scaled=x * factor, total=jnp.sum(jnp.where(mask, x, 0)))


def args(n: int = 5):
    return np.arange(n, dtype=np.float32), np.arange(n) % 2 == 0


def run(factor: int = 3, n: int = 5) -> Pair:
    """The program through `gfjax.aot` (tagged: it is not a gfjax function)."""
    return aot.call(scale_and_sum, *args(n), tag=("tests.reliability", "scale_and_sum"), factor=factor)


def assert_correct(out: Pair, factor: int = 3, n: int = 5) -> None:
    expected = scale_and_sum(*args(n), factor=factor)
    assert type(out) is Pair
    for got, want in zip(out, expected):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def entries(folder) -> list:
    """Stored executables in `folder` (not markers, not exports, not temporaries)."""
    return sorted(p for p in folder.iterdir() if p.name.endswith(SUFFIX) and p.name.count(".") == 1)


def new_process() -> None:
    """Forget what this process loaded, as a new `gfjax` process would start."""
    calls._loaded.clear()
    calls._from_disk.clear()
    calls._plain.clear()


@pytest.fixture
def private(tmp_path, monkeypatch):
    """An enabled, private program cache folder; warnings of earlier tests forgotten."""
    monkeypatch.setitem(aot_folder._state, "warned", False)
    folder = aot.enable(tmp_path / "cache")
    assert folder is not None and folder.stat().st_mode & 0o777 == 0o700
    yield folder
    aot.disable()


def forbid_loading(monkeypatch) -> list:
    """Fail on any unpickling or executable load from the cache; returns the list of compiles
    (each is a program computed without the cache)."""
    from jax.experimental import serialize_executable

    def refuse(*_, **__):
        raise AssertionError("a cache artifact was loaded")

    read = store.read_entry

    def read_nothing(*a, **k):
        payload = read(*a, **k)
        assert payload is None, "a cache artifact was unpickled"
        return payload

    monkeypatch.setattr(store, "read_entry", read_nothing)
    monkeypatch.setattr(serialize_executable, "deserialize_and_load", refuse)
    compiles = []
    real = jax.stages.Lowered.compile

    def counted(self, *a, **k):
        compiles.append(self)
        return real(self, *a, **k)

    monkeypatch.setattr(jax.stages.Lowered, "compile", counted)
    return compiles


def fake_owner(monkeypatch, *, match, uid: int) -> None:
    """`os.fstat` reports user `uid` as the owner of descriptors whose path ends with `match`
    (tests cannot chown: this stands in for a file or folder another user owns)."""
    real = os.fstat

    def fstat(fd):
        info = real(fd)
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            return info
        if not target.endswith(match):
            return info
        fields = list(tuple(info)[:10])
        fields[4] = uid
        return os.stat_result(fields)

    monkeypatch.setattr(aot_folder.os, "fstat", fstat)


def one_warning(err: str) -> None:
    lines = [line for line in err.splitlines() if line]
    assert len(lines) == 1 and lines[0].startswith("gfjax: warning: "), err
