"""Cache attack: an artifact inside the private folder that other users can write (mode 0666),
or a symbolic link in place of an artifact. Neither is read: the program is compiled without
the cache, one warning line, and our own entry replaces it."""
from __future__ import annotations

import os

from cache_attack_helpers import assert_correct, entries, forbid_loading, new_process, one_warning, private, run

from gfjax.aot import calls

__all__ = ["private"]


def test_world_writable_artifact_is_not_loaded(private, monkeypatch, capfd):
    run()
    (entry,) = entries(private)
    entry.chmod(0o666)
    new_process()
    with monkeypatch.context() as patch:
        compiles = forbid_loading(patch)
        assert_correct(run())
        assert len(compiles) == 1                           # computed without the cache
    err = capfd.readouterr().err
    one_warning(err)
    assert "can be written by other users" in err
    assert entry.stat().st_mode & 0o777 == 0o600            # replaced by an entry of ours
    new_process()
    assert_correct(run())
    assert calls._from_disk                                 # ... which later processes load


def test_symbolic_link_artifact_is_not_followed(private, tmp_path, monkeypatch, capfd):
    run()
    (entry,) = entries(private)
    planted = tmp_path / "elsewhere.gfjaxexe"
    planted.write_bytes(entry.read_bytes())
    entry.unlink()
    entry.symlink_to(planted)
    new_process()
    compiles = forbid_loading(monkeypatch)
    assert_correct(run())
    assert len(compiles) == 1
    one_warning(capfd.readouterr().err)
    assert not entry.is_symlink() and entry.stat().st_mode & 0o777 == 0o600


def test_fifo_in_place_of_an_artifact_does_not_hang(private, monkeypatch):
    run()
    (entry,) = entries(private)
    entry.unlink()
    os.mkfifo(entry, 0o600)
    new_process()
    compiles = forbid_loading(monkeypatch)
    assert_correct(run())
    assert len(compiles) == 1 and entry.is_file()
