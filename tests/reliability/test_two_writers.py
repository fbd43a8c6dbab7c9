"""Two writers of one new output: without `--force`, exactly one succeeds and the other is told,
however close together they finish; nothing of the loser is left behind."""
from __future__ import annotations

import errno
import os
import threading

import numpy as np
import pytest

import gfjax
from gfjax.errors import InputError
from gfjax.io import atomic, stream
from gfjax.io import las as las_io


def cloud(z: float = 0.0):
    rng = np.random.default_rng(0)
    return gfjax.Cloud.from_xyz(np.column_stack([rng.uniform(0, 10, (50, 2)), np.full(50, z)]))


def leftovers(folder):
    return [p for p in os.listdir(folder) if atomic.is_temporary(p)]


def test_an_exclusive_write_never_replaces_a_file_written_meanwhile(tmp_path):
    out = tmp_path / "out.las"
    with pytest.raises(InputError, match="out.las: exists; pass --force to overwrite it .written by another"):
        las_io.write(cloud(), out, exclusive=True, before_commit=lambda: out.write_bytes(b"theirs"))
    assert out.read_bytes() == b"theirs"
    assert leftovers(tmp_path) == []


def test_a_plain_write_replaces_as_open_does(tmp_path):
    out = tmp_path / "out.las"
    las_io.write(cloud(), out, before_commit=lambda: out.write_bytes(b"theirs"))
    assert len(gfjax.read(out).las.points) == 50


def test_of_two_writers_finishing_together_one_wins(tmp_path):
    out = tmp_path / "out.las"
    barrier = threading.Barrier(2)
    outcome = {}

    def writer(name, z):
        try:
            las_io.write(cloud(z), out, exclusive=True, before_commit=lambda: barrier.wait(timeout=30))
            outcome[name] = "written"
        except InputError as err:
            outcome[name] = str(err)

    threads = [threading.Thread(target=writer, args=(name, z)) for name, z in (("a", 1.0), ("b", 2.0))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert sorted(outcome.values()).count("written") == 1, outcome
    loser = next(v for v in outcome.values() if v != "written")
    assert "written by another process meanwhile" in loser
    winner = next(k for k, v in outcome.items() if v == "written")
    assert gfjax.read(out).xyz_m[0, 2] == {"a": 1.0, "b": 2.0}[winner]
    assert leftovers(tmp_path) == []


def test_without_hard_links_the_name_is_claimed_exclusively(tmp_path, monkeypatch):
    def no_link(*_):
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_link)
    out = tmp_path / "out.las"
    las_io.write(cloud(), out, exclusive=True)
    assert len(gfjax.read(out).las.points) == 50
    with pytest.raises(InputError, match="exists"):
        las_io.write(cloud(), tmp_path / "again.las", exclusive=True,
                     before_commit=lambda: (tmp_path / "again.las").write_bytes(b"theirs"))
    assert (tmp_path / "again.las").read_bytes() == b"theirs"
    assert leftovers(tmp_path) == []


def test_a_copy_written_out_of_core_is_exclusive_too(tmp_path, monkeypatch):
    source = tmp_path / "in.las"
    gfjax.write(cloud(), source)
    out = tmp_path / "out.las"
    publish = atomic._publish

    def late(tmp, target, *, exclusive):          # another process finishes first
        target.write_bytes(b"theirs")
        return publish(tmp, target, exclusive=exclusive)

    monkeypatch.setattr(atomic, "_publish", late)
    with pytest.raises(InputError, match="written by another process meanwhile"):
        stream.relabel(source, out, np.ones(50, bool), exclusive=True)
    assert out.read_bytes() == b"theirs"
    assert leftovers(tmp_path) == []


def test_a_staged_copy_is_committed_exclusively_and_removed_when_it_loses(tmp_path):
    out = tmp_path / "out.las"
    staged = atomic.temporary_name(out)
    staged.write_bytes(b"mine")
    out.write_bytes(b"theirs")
    with pytest.raises(InputError, match="written by another process meanwhile"):
        atomic.commit(staged, out, exclusive=True)
    assert out.read_bytes() == b"theirs" and not staged.exists()
    staged.write_bytes(b"mine")
    atomic.commit(staged, out)                    # --force: replaced
    assert out.read_bytes() == b"mine"
