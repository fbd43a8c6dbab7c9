"""`gfjax COMMAND --help`: what it says is what the command does, with nothing users cannot read."""
from __future__ import annotations

import inspect
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
    assert f"ground filter (default {methods.DEFAULT_METHOD}): {', '.join(methods.names())}" in out
    assert f"{methods.DEFAULT_METHOD} (default):" in out


@pytest.mark.parametrize("command", ["filter", "eval"])
def test_help_lists_every_methods_presets(capsys, fake_methods, command):
    out = _one_line(_help(capsys, command))
    for name in methods.names():
        presets = ", ".join(methods.get(name).presets) or "none"
        assert re.search(rf"\b{re.escape(name)}( \(default\))?: {re.escape(presets)}", out), (name, out)
    assert "fake: generous" in out


def test_filter_help_says_which_methods_take_tile_size_and_buffer(capsys):
    out = _one_line(_help(capsys, "filter"))
    tiling = out.split("--tile-size and --buffer apply to the methods that tile:")[1]
    tiling, defaults = tiling.split(";")[0].split("(default")
    for name in methods.names():
        takes = "tiling" in inspect.signature(methods.get(name).filter).parameters
        assert takes == methods.get(name).tiles, name
        assert (re.search(rf"\b{name}\b", tiling) is not None) == takes, name
    assert re.search(r"\bsmrf\b", tiling) and re.search(r"\bdmf\b", tiling) and not re.search(r"\bcsf\b", tiling)
    assert defaults.strip() == "500 m tiles, 50 m buffers)"


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
