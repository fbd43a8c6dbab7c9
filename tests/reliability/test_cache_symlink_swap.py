"""Cache attack: after the process checked its cache folder, the folder (or one above it) is
swapped for a symbolic link to a folder someone else filled. The path is walked again with
O_NOFOLLOW at each use: plain jit, one warning line, nothing of the planted folder read."""
from __future__ import annotations

import shutil

from cache_attack_helpers import assert_correct, entries, forbid_loading, new_process, one_warning, private, run

from gfjax import aot
from gfjax.aot import calls
from gfjax.aot import folder as aot_folder

__all__ = ["private"]


def _swap_for_link(folder, tmp_path):
    """Move `folder` aside, fill a look-alike with its entries, link it in `folder`'s place."""
    planted = tmp_path / "planted"
    shutil.copytree(folder, planted)
    folder.rename(tmp_path / "moved")
    folder.symlink_to(planted, target_is_directory=True)
    return planted


def test_folder_swapped_for_a_link_after_start(private, tmp_path, monkeypatch, capfd):
    run()
    planted = _swap_for_link(private, tmp_path)
    assert len(entries(planted)) == 1
    new_process()
    compiles = forbid_loading(monkeypatch)
    assert_correct(run())
    assert_correct(run(factor=5), factor=5)
    assert compiles == [] and calls._loaded == {}           # plain jit
    assert len(entries(planted)) == 1                       # nothing written through the link
    err = capfd.readouterr().err
    one_warning(err)
    assert "symbolic link" in err


def test_folder_above_swapped_for_a_link_after_start(tmp_path, monkeypatch, capfd):
    monkeypatch.setitem(aot_folder._state, "warned", False)
    folder = aot.enable(tmp_path / "home" / "cache")
    run()
    planted = tmp_path / "planted"
    shutil.copytree(tmp_path / "home", planted)
    (tmp_path / "home").rename(tmp_path / "moved")
    (tmp_path / "home").symlink_to(planted, target_is_directory=True)
    assert folder.exists() and len(entries(folder)) == 1    # the same path, another folder
    new_process()
    compiles = forbid_loading(monkeypatch)
    assert_correct(run())
    assert compiles == [] and calls._loaded == {}
    one_warning(capfd.readouterr().err)
    aot.disable()
