"""`gfjax COMMAND --help`: what it says is what the command does, with nothing users cannot read."""
from __future__ import annotations

import dataclasses
import re

import pytest
from cli_helpers import fake_methods, no_compilation_cache, run_cli  # noqa: F401

from gfjax import methods
from gfjax.cli import main as cli_main


def _help(capsys, *command) -> str:
    code, out, err = run_cli(capsys, *command, "--help")
    assert code == 0, err
    return out


def _one_line(text: str) -> str:
    return " ".join(text.split())


def test_filter_help_names_the_default_method(capsys):
    out = _one_line(_help(capsys, "filter"))
    assert "gfjax.methods" not in out
    assert f"ground filter (default {methods.DEFAULT_METHOD}): {', '.join(methods.METHODS)}" in out
    assert f"{methods.DEFAULT_METHOD} (default):" in out


@pytest.mark.parametrize("command", ["filter", "eval"])
def test_help_lists_every_methods_presets(capsys, fake_methods, command):
    out = _one_line(_help(capsys, command))
    for name in methods.METHODS:
        presets = ", ".join(methods.get(name).PRESETS) or "none"
        assert re.search(rf"\b{re.escape(name)}( \(default\))?: {re.escape(presets)}", out), (name, out)
    assert "fake: generous" in out


def test_filter_help_says_which_methods_take_tile_size_and_buffer(capsys):
    out = _one_line(_help(capsys, "filter"))
    tiling = out.split("--tile-size and --buffer apply to the methods that tile:")[1]
    tiling = tiling.split(";")[0]
    for name in methods.METHODS:
        fields = {f.name for f in dataclasses.fields(methods.get(name).Config)}
        assert (re.search(rf"\b{name} \(default", tiling) is not None) == ({"tile_size_m", "buffer_m"} <= fields), name
    assert re.search(r"\bsmrf \(default 500 m, buffer 50 m\)", tiling)


@pytest.mark.parametrize("command", [None, *cli_main.SUBCOMMANDS])
def test_help_cites_nothing_users_do_not_have(capsys, command):
    out = _help(capsys, *([command] if command else []))
    assert "SPEC" not in out and "../shared" not in out


def test_parsing_options_imports_no_method(monkeypatch):
    """The presets in the help import every method (JAX): only when the help is printed."""
    def refuse(name):
        raise AssertionError(f"method {name} imported to parse options")

    monkeypatch.setattr(methods, "get", refuse)
    for argv in (["filter", "a.laz", "-o", "b.laz", "--preset", "urban"], ["eval", "a.laz", "--method", "pmf"]):
        parser, _ = cli_main.build_parser(argv)
        assert parser.parse_args(argv).command == argv[0]
