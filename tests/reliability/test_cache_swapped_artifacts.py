"""Cache attack (or accident): two entries' files exchanged, an entry from another program
(stale), a damaged entry, or a stored program that does not fit its caller. Each is detected
before or at the call: the right result, computed without the cache, and the entry replaced;
never an exit 1, never the other program's result."""
from __future__ import annotations

import numpy as np
from cache_attack_helpers import assert_correct, entries, forbid_loading, new_process, private, run

from gfjax.aot import calls, store

__all__ = ["private"]


def test_swapped_artifacts_are_compiled_again_and_replaced(private, monkeypatch):
    run(factor=2)
    first = set(entries(private))
    run(factor=3)                                           # same shapes, another program
    (two,) = first
    (three,) = set(entries(private)) - first
    blob_two, blob_three = two.read_bytes(), three.read_bytes()
    two.write_bytes(blob_three)
    three.write_bytes(blob_two)
    new_process()
    with monkeypatch.context() as patch:
        compiles = forbid_loading(patch)
        assert_correct(run(factor=2), factor=2)             # not the factor-3 program
        assert_correct(run(factor=3), factor=3)
        assert len(compiles) == 2                           # both computed without the cache
    assert two.read_bytes() != blob_three and three.read_bytes() != blob_two
    new_process()
    assert_correct(run(factor=2), factor=2)                 # the replaced entries load
    assert_correct(run(factor=3), factor=3)
    assert len(calls._from_disk) == 2


def test_damaged_artifact_is_compiled_again_and_replaced(private, monkeypatch):
    run()
    (entry,) = entries(private)
    blob = bytearray(entry.read_bytes())
    blob[-100] ^= 0xFF                                      # one flipped byte in the body
    entry.write_bytes(bytes(blob))
    new_process()
    compiles = forbid_loading(monkeypatch)
    assert_correct(run())
    assert len(compiles) == 1 and entry.read_bytes() != bytes(blob)


def test_program_that_does_not_fit_its_caller_falls_back(private, monkeypatch):
    """A loaded program that fails on its arguments (say, stale machine code whose key
    collides): plain jit gives the result, the entry is removed and stored again next time."""
    run()
    (entry,) = entries(private)
    new_process()

    def misfit(*_):
        raise TypeError("Argument types differ from the types for which this computation was compiled")

    real = store.load
    monkeypatch.setattr(store, "load", lambda *a: misfit if real(*a) is not None else None)
    assert_correct(run())
    assert not entry.exists() and calls._loaded == {}
    monkeypatch.undo()
    assert_correct(run())
    assert entry.exists()


def test_unrelated_file_under_an_entry_name_is_not_unpickled(private, monkeypatch):
    run()
    (entry,) = entries(private)
    entry.write_bytes(b"\x80\x05cos\nsystem\n(S'false'\ntR.")   # a pickle that would run code
    new_process()
    compiles = forbid_loading(monkeypatch)
    assert_correct(run())
    assert len(compiles) == 1


def test_gfjax_filter_with_swapped_artifacts_exits_0_with_the_same_labels(tmp_path, monkeypatch, capsys):
    """The whole command: DMF stores three programs; two entries' files are exchanged; the next
    `gfjax filter` exits 0 and writes the labels of the first run."""
    import laspy
    from bench_helpers import write_scene_laz

    from gfjax.cli.main import main

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("GFJAX_EXPORT_CACHE", raising=False)
    scene = write_scene_laz(tmp_path / "scene.laz", labelled=False)
    first, second = tmp_path / "first.laz", tmp_path / "second.laz"
    assert main(["filter", str(scene), "-o", str(first), "--method", "dmf"]) == 0
    folder = tmp_path / "cache" / "gfjax" / "export"
    stored = entries(folder)
    assert len(stored) >= 2
    a, b = stored[:2]
    blob_a, blob_b = a.read_bytes(), b.read_bytes()
    a.write_bytes(blob_b)
    b.write_bytes(blob_a)
    new_process()
    assert main(["filter", str(scene), "-o", str(second), "--method", "dmf"]) == 0, capsys.readouterr().err
    np.testing.assert_array_equal(laspy.read(second).classification, laspy.read(first).classification)
    for entry in (a, b):                                    # replaced by the right programs
        assert entry.read_bytes().startswith(store.MAGIC + entry.name.split(".")[0].encode() + b"\n")
