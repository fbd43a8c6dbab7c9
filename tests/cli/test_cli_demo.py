"""`gfjax demo`: runs on the shipped sample with no arguments beyond the output folder.

`demo.run` is called directly: `gfjax.cli.main.main` would also switch on JAX's persistent
compilation cache in the user's cache folder for the rest of the test session.
"""
from __future__ import annotations

import argparse

import numpy as np
import pytest
import rasterio

import gfjax
from gfjax.cli import demo
from gfjax.cli.main import build_parser
from gfjax.data import demo_sample
from gfjax.errors import InputError


def test_demo_is_a_subcommand_without_required_arguments():
    parser, module = build_parser(["demo"])
    assert module is demo
    assert parser.parse_args(["demo"]).out == demo.DEFAULT_OUT


def test_demo_writes_laz_dtm_png(tmp_path, capsys):
    out = tmp_path / "demo"
    assert demo.run(argparse.Namespace(out=str(out), force=False)) == 0
    printed = capsys.readouterr().out
    assert "total error" in printed and str(out / "samp12-vote.laz") in printed
    classified = gfjax.read(out / "samp12-vote.laz")
    original = gfjax.read(demo_sample())
    assert classified.n_points == original.n_points
    np.testing.assert_array_equal(classified.xyz, original.xyz)
    ground = classified.classification == 2
    assert 0.4 < ground.mean() < 0.6
    with rasterio.open(out / "samp12-dtm.tif") as tif:
        assert tif.crs.to_epsg() == 32632 and tif.res == (1.0, 1.0)
    assert (out / "samp12-demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_bad_output_folder(tmp_path):
    with pytest.raises(InputError, match="--out"):
        demo.run(argparse.Namespace(out=str(tmp_path / "missing" / "demo"), force=False))
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        demo.run(argparse.Namespace(out=str(tmp_path / "file"), force=False))


def test_demo_overwrites_an_earlier_run_only_with_force(tmp_path):
    (tmp_path / "samp12-dtm.tif").write_text("an earlier run")
    with pytest.raises(InputError, match=r"^--out .*samp12-dtm.tif: exists; pass --force to overwrite it$"):
        demo.run(argparse.Namespace(out=str(tmp_path), force=False))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["samp12-dtm.tif"]
    assert build_parser(["demo", "--force"])[0].parse_args(["demo", "--force"]).force
