"""`gfjax warmup`: needs the program cache, names the methods it can prepare, bad options."""
from __future__ import annotations

import dataclasses

import cli_helpers
import pytest
from cli_helpers import no_compilation_cache  # noqa: F401 (autouse fixture)

from gfjax import aot, smrf
from gfjax.aot import calls


def test_warmup_needs_the_program_cache(capsys):
    code, _, err = cli_helpers.run_cli(capsys, "warmup")
    assert code == 2 and "the program cache is off" in err


def test_warmup_names_a_method_without_canonical_shapes(capsys, tmp_path, monkeypatch):
    aot.enable(tmp_path / "export")
    code, _, err = cli_helpers.run_cli(capsys, "warmup", "--methods", "masf")
    assert code == 2 and "masf has no canonical shapes" in err and "dmf" in err


def test_warmup_prepares_each_method_once(capsys, tmp_path, monkeypatch):
    aot.enable(tmp_path / "export")
    calls = []
    monkeypatch.setattr(smrf, "METHOD", dataclasses.replace(smrf.METHOD, warm=lambda progress=False: calls.append(progress) or 30))
    code, out, _ = cli_helpers.run_cli(capsys, "-q", "warmup", "--methods", "smrf")
    assert code == 0 and calls == [True]
    assert "smrf: 30 input shapes ready" in out and str(tmp_path / "export") in out


@pytest.mark.parametrize("argv", [["warmup", "--methods", "nope"], ["warmup", "--methods"]])
def test_warmup_bad_options_exit_2(capsys, argv):
    code, _, err = cli_helpers.run_cli(capsys, *argv)
    assert code == 2 and err.startswith("gfjax: error:")


def test_warmup_does_not_announce_each_compile(capsys, tmp_path, monkeypatch):
    aot.enable(tmp_path / "export")

    def warm(progress=False):
        hook = calls._state.get("on_compile")
        if hook is not None:
            hook("gfjax.smrf.stages")              # what a compile inside warm would call
        return 30

    monkeypatch.setattr(smrf, "METHOD", dataclasses.replace(smrf.METHOD, warm=warm))
    code, _, err = cli_helpers.run_cli(capsys, "warmup", "--methods", "smrf")
    assert code == 0 and "compiling" not in err
