"""Cache attack: an artifact (or the cache folder itself) owned by another user.

Tests cannot chown, so `os.fstat` reports another owner for the planted file. The program is
compiled without the cache, the foreign file is never unpickled, one warning line says why,
and the entry is replaced by one of ours."""
from __future__ import annotations

from cache_attack_helpers import (
    assert_correct,
    entries,
    fake_owner,
    forbid_loading,
    new_process,
    one_warning,
    private,
    run,
)

from gfjax import aot
from gfjax.aot import calls
from gfjax.aot import folder as aot_folder

__all__ = ["private"]


def test_foreign_owned_artifact_is_not_loaded(private, monkeypatch, capfd):
    run()
    (entry,) = entries(private)
    new_process()
    fake_owner(monkeypatch, match=entry.name, uid=12345)
    compiles = forbid_loading(monkeypatch)
    assert_correct(run())
    assert len(compiles) == 1                               # computed without the cache
    err = capfd.readouterr().err
    one_warning(err)
    assert f"{entry.name} is owned by user 12345" in err


def test_foreign_owned_folder_is_refused_at_use_time(private, monkeypatch, capfd):
    run()
    new_process()
    fake_owner(monkeypatch, match=private.name, uid=12345)  # the folder changed hands after start
    compiles = forbid_loading(monkeypatch)
    assert_correct(run())
    assert compiles == [] and calls._loaded == {}           # plain jit
    err = capfd.readouterr().err
    one_warning(err)
    assert "owned by user 12345" in err


def test_foreign_owned_folder_is_refused_at_start(tmp_path, monkeypatch, capfd):
    monkeypatch.setitem(aot_folder._state, "warned", False)
    (tmp_path / "cache").mkdir(mode=0o700)
    fake_owner(monkeypatch, match="cache", uid=12345)
    assert aot.enable(tmp_path / "cache") is None and aot.enabled_folder() is None
    assert_correct(run())
    one_warning(capfd.readouterr().err)
