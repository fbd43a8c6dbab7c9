"""One rule for every command that writes files: an existing output is overwritten only with
`--force` (exit 2 and one line naming it otherwise, before any work)."""
from __future__ import annotations

import os

import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli, write_scene  # noqa: F401

# command -> (arguments after the input, the option naming the existing output, its file name)
COMMANDS = {
    "filter": (["filter", "{src}", "-o", "{out}", "--method", "fake"], "-o", "out.laz"),
    "filter --dtm": (["filter", "{src}", "-o", "{dir}/new.laz", "--method", "fake", "--dtm", "{out}"], "--dtm", "d.tif"),
    "dtm": (["dtm", "{src}", "-o", "{out}"], "-o", "d.tif"),
    "dtm --hillshade": (["dtm", "{src}", "-o", "{dir}/new.tif", "--hillshade", "{out}"], "--hillshade", "h.png"),
    "eval --json": (["eval", "{src}", "--reference", "{src}", "--json", "{out}"], "--json", "m.json"),
    "tune": (["tune", "{src}", "-o", "{out}"], "-o", "p.json"),
    "train": (["train", "{src}", "-o", "{out}"], "-o", "m.eqx"),
    "bench --json": (["bench", "{src}", "--methods", "none", "--peers", "none", "--json", "{out}"], "--json", "b.json"),
    "bench --plot": (["bench", "{src}", "--methods", "none", "--peers", "none", "--plot", "{out}"], "--plot", "b.png"),
}


def _argv(template, **fields):
    return [a.format(**{k: str(v) for k, v in fields.items()}) for a in template]


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_command_refuses_an_existing_output_without_force(tmp_path, capsys, fake_methods, command):
    template, option, name = COMMANDS[command]
    src = write_scene(tmp_path / "in.laz")
    out = tmp_path / name
    out.write_bytes(b"an earlier result")
    code, _, err = run_cli(capsys, *_argv(template, src=src, out=out, dir=tmp_path))
    assert code == 2
    expected = f"gfjax: error: {option} {out}: exists; pass --force to overwrite it"
    assert error_line(err) == expected + (" (or --resume to continue training it)" if command == "train" else "")
    assert out.read_bytes() == b"an earlier result"
    assert sorted(os.listdir(tmp_path)) == sorted(["in.laz", name])


@pytest.mark.parametrize("command", ["filter", "filter --dtm", "eval --json"])
def test_force_overwrites_an_existing_output(tmp_path, capsys, fake_methods, command):
    pytest.importorskip("gfjax.dtm")
    template, _, name = COMMANDS[command]
    src = write_scene(tmp_path / "in.laz")
    out = tmp_path / name
    out.write_bytes(b"an earlier result")
    code, _, err = run_cli(capsys, *_argv(template, src=src, out=out, dir=tmp_path), "--force")
    assert code == 0, err
    assert out.read_bytes() != b"an earlier result"


def test_several_inputs_refuse_existing_outputs_before_the_first_file(tmp_path, capsys, fake_methods):
    (tmp_path / "in").mkdir()
    (tmp_path / "out").mkdir()
    sources = [write_scene(tmp_path / "in" / name) for name in ("a.las", "b.las", "c.las")]
    for name in ("b.las", "c.las"):
        (tmp_path / "out" / name).write_bytes(b"an earlier result")
    code, _, err = run_cli(capsys, "filter", *sources, "-o", tmp_path / "out", "--method", "fake", "--independent")
    assert code == 2
    assert error_line(err) == (f"gfjax: error: -o {tmp_path / 'out' / 'b.las'}: exists, and 1 more of the outputs; "
                               "pass --force to overwrite them")
    assert fake_methods["fake"].calls == [] and sorted(os.listdir(tmp_path / "out")) == ["b.las", "c.las"]
    code, _, err = run_cli(capsys, "filter", *sources, "-o", tmp_path / "out", "--method", "fake", "--independent",
                           "--force")
    assert code == 0, err
    assert len(fake_methods["fake"].calls) == 3
