"""glibc's heap set for large windows (`gfjax.heap`): what is asked of it, and when not."""
from __future__ import annotations

import os

import pytest

from gfjax import heap

_ENV = ("MALLOC_ARENA_MAX", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "GLIBC_TUNABLES", "NUMPY_MADVISE_HUGEPAGE")


class _Libc:
    """glibc's two calls, recorded instead of made."""

    def __init__(self):
        self.calls = []

    def mallopt(self, option, value):
        self.calls.append((option, value))
        return 1

    def malloc_trim(self, pad):
        self.calls.append(("trim", pad))
        return 1


@pytest.fixture
def libc(monkeypatch):
    fake = _Libc()
    monkeypatch.setattr(heap, "_libc", lambda: fake)
    monkeypatch.setattr(heap, "_numpy_huge_pages", lambda: lambda on: fake.calls.append(("numpy huge pages", on)))
    for name in _ENV:
        monkeypatch.delenv(name, raising=False)
    return fake


def test_tune_asks_one_arena_a_core_and_freed_memory_kept_and_no_huge_pages(libc):
    heap.tune()
    assert libc.calls == [("numpy huge pages", False), (-8, os.cpu_count()), (-3, heap.MAPPED_APART_BYTES),
                          (-1, heap.KEEP_FREED_BYTES)]
    assert 0 < heap.KEEP_FREED_BYTES < 2 ** 31                 # mallopt takes a C int


@pytest.mark.parametrize(("name", "value", "asked"), [
    ("MALLOC_ARENA_MAX", "4", [(-3, heap.MAPPED_APART_BYTES), (-1, heap.KEEP_FREED_BYTES)]),
    ("MALLOC_MMAP_THRESHOLD_", "131072", ["arenas"]),
    ("MALLOC_TRIM_THRESHOLD_", "131072", ["arenas"]),
    ("GLIBC_TUNABLES", "glibc.malloc.trim_threshold=131072", []),
    ("GLIBC_TUNABLES", "glibc.rtld.optional_static_tls=1024", ["arenas", (-3, heap.MAPPED_APART_BYTES), (-1, heap.KEEP_FREED_BYTES)]),
])
def test_the_users_own_heap_settings_win(libc, monkeypatch, name, value, asked):
    monkeypatch.setenv(name, value)
    heap.tune()
    assert libc.calls == [("numpy huge pages", False), *((-8, os.cpu_count()) if a == "arenas" else a for a in asked)]


def test_the_users_own_numpy_huge_pages_setting_wins(libc, monkeypatch):
    monkeypatch.setenv("NUMPY_MADVISE_HUGEPAGE", "1")
    heap.tune()
    assert ("numpy huge pages", False) not in libc.calls


def test_numpys_own_switch_is_found_and_turns_huge_pages_off_and_on_again():
    """This numpy has the switch `tune` uses; it answers what was set before."""
    setter = heap._numpy_huge_pages()
    assert setter is not None
    was = setter(False)
    try:
        assert setter(False) is False
    finally:
        setter(was)


def test_trim_gives_the_free_pages_back(libc):
    heap.trim()
    assert libc.calls == [("trim", 0)]


def test_without_glibc_nothing_is_asked_of_the_heap(monkeypatch):
    monkeypatch.setattr(heap, "_libc", lambda: None)
    monkeypatch.setattr(heap, "_numpy_huge_pages", lambda: None)
    heap.tune()
    heap.trim()


@pytest.mark.skipif(not os.uname().sysname == "Linux", reason="glibc's heap")
def test_the_real_glibc_is_found_and_takes_the_settings():
    """On this machine (Linux, glibc) the calls reach glibc: the settings are accepted."""
    libc = heap._libc()
    if libc is None:
        pytest.skip("not glibc")
    assert libc.mallopt(-8, max(1, os.cpu_count() or 1)) == 1
    heap.trim()
