"""Cache attack: the private folder (or one above it) becomes writable by the group or by
others after the process started. Checked at each use: plain jit, one warning line, nothing
read from or written to the folder."""
from __future__ import annotations

from cache_attack_helpers import assert_correct, entries, forbid_loading, new_process, one_warning, private, run

from gfjax import aot
from gfjax.aot import calls
from gfjax.aot import folder as aot_folder

__all__ = ["private"]


def test_group_writable_folder_is_refused_at_use_time(private, monkeypatch, capfd):
    run()
    before = {p.name: p.stat().st_mtime_ns for p in private.iterdir()}
    private.chmod(0o770)
    new_process()
    compiles = forbid_loading(monkeypatch)
    assert_correct(run())
    assert_correct(run(factor=4), factor=4)                 # a new program: not stored there either
    assert compiles == [] and calls._loaded == {}           # plain jit
    assert {p.name: p.stat().st_mtime_ns for p in private.iterdir()} == before
    err = capfd.readouterr().err
    one_warning(err)
    assert "can be written by other users (mode 0770" in err


def test_writable_folder_above_is_refused(tmp_path, monkeypatch, capfd):
    monkeypatch.setitem(aot_folder._state, "warned", False)
    parent = tmp_path / "shared"
    parent.mkdir()
    parent.chmod(0o777)                                     # not sticky: others may rename ours
    assert aot.enable(parent / "cache") is None
    assert_correct(run())
    one_warning(capfd.readouterr().err)


def test_group_writable_folder_is_refused_at_start(tmp_path, monkeypatch, capfd):
    monkeypatch.setitem(aot_folder._state, "warned", False)
    folder = tmp_path / "cache"
    folder.mkdir()
    folder.chmod(0o775)
    assert aot.enable(folder) is None and aot.enabled_folder() is None
    assert folder.stat().st_mode & 0o777 == 0o775           # not "fixed": its files may be foreign
    one_warning(capfd.readouterr().err)


def test_readable_folder_of_ours_is_made_private(tmp_path):
    folder = tmp_path / "cache"
    folder.mkdir()
    folder.chmod(0o755)                                     # e.g. made by an older gfjax
    assert aot.enable(folder) == folder
    assert folder.stat().st_mode & 0o777 == 0o700
    assert entries(folder) == []
