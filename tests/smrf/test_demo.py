"""`gfjax demo`: runs on the shipped sample with no arguments beyond the output folder."""
from __future__ import annotations

import numpy as np
import rasterio

import gfjax
from gfjax.cli.main import main
from gfjax.data import demo_sample


def test_demo_writes_laz_dtm_png(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "total error" in printed and str(out / "samp12-smrf.laz") in printed
    classified = gfjax.read(out / "samp12-smrf.laz")
    original = gfjax.read(demo_sample())
    assert classified.n_points == original.n_points
    np.testing.assert_array_equal(classified.xyz, original.xyz)
    ground = classified.classification == 2
    assert 0.4 < ground.mean() < 0.6
    with rasterio.open(out / "samp12-dtm.tif") as tif:
        assert tif.crs.to_epsg() == 32632 and tif.res == (1.0, 1.0)
    assert (out / "samp12-demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_bad_output_folder(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "missing" / "demo")]) == 2
    assert "--out" in capsys.readouterr().err
