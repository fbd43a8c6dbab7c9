"""`gfjax dtm` over a survey's files: one raster per file whose TIN takes its neighbours' ground
(`--buffer`), so the DTMs and CHMs of the pieces are those of the whole; `--mosaic` joins them."""
from __future__ import annotations

import numpy as np
import pytest
import rasterio
from cli_helpers import error_line, run_cli
from test_cli_hag import terrain, write

NODATA = -9999.0


@pytest.fixture
def pieces(tmp_path):
    """One classified scene, whole and cut at x = 25 m (a cell edge) into two files."""
    xyz, cls, _ = terrain(n=6000, seed=3)
    clear = np.abs(xyz[:, 0] - 25.0) > 0.01           # no point stored (to 1 mm) on the cut
    xyz, cls = xyz[clear], cls[clear]
    whole = write(tmp_path / "whole.laz", xyz, cls)
    folder = tmp_path / "pieces"
    folder.mkdir()
    west = xyz[:, 0] < 25.0
    paths = [write(folder / "a.laz", xyz[west], cls[west]), write(folder / "b.laz", xyz[~west], cls[~west])]
    return whole, paths


def read(path):
    with rasterio.open(path) as src:
        return src.read(1), src.transform


def same_cells(piece, whole):
    """`piece` against the cells of `whole` it covers (one lattice): both arrays there."""
    z, t = read(piece)
    zw, tw = read(whole)
    col, row = round((t.c - tw.c) / tw.a), round((t.f - tw.f) / tw.e)
    return z, zw[row:row + z.shape[0], col:col + z.shape[1]]


@pytest.mark.parametrize("surface", ["ground", "chm"])
def test_each_files_raster_is_the_whole_surveys_on_its_cells(pieces, tmp_path, capsys, surface):
    whole, paths = pieces
    out = tmp_path / "out"
    out.mkdir()
    assert run_cli(capsys, "dtm", whole, "-o", tmp_path / "whole.tif", "--surface", surface)[0] == 0
    code, stdout, err = run_cli(capsys, "dtm", *paths, "-o", out, "--surface", surface, "--mosaic", tmp_path / "m.vrt")
    assert code == 0, err
    assert "of its neighbours'" in stdout and "mosaic of 2 files" in stdout
    for path in paths:
        got, want = same_cells(out / path.with_suffix(".tif").name, tmp_path / "whole.tif")
        valid = got != NODATA
        np.testing.assert_allclose(got[valid], want[valid], atol=1e-9, err_msg=path.name)
        # a CHM cell of no point of the file's own is nodata: only on the grid's outer edge
        inner = np.zeros_like(valid)
        inner[1:-1, 1:-1] = True
        assert not np.any(~valid & (want != NODATA) & inner), path.name
    mosaic, whole_z = same_cells(tmp_path / "m.vrt", tmp_path / "whole.tif")
    np.testing.assert_allclose(mosaic, whole_z, atol=1e-9)


def test_without_the_buffer_the_heights_at_the_border_are_the_files_own(pieces, tmp_path, capsys):
    whole, paths = pieces
    for name, extra in (("with", []), ("without", ["--buffer", "0"])):
        (tmp_path / name).mkdir()
        assert run_cli(capsys, "dtm", *paths, "-o", tmp_path / name, "--surface", "chm", *extra)[0] == 0
    assert run_cli(capsys, "dtm", whole, "-o", tmp_path / "whole.tif", "--surface", "chm")[0] == 0
    errors = {}
    for name in ("with", "without"):
        got, want = same_cells(tmp_path / name / "b.tif", tmp_path / "whole.tif")
        valid = got != NODATA
        errors[name] = float(np.abs(got - want)[valid].max())
    assert errors["with"] < 1e-9 < errors["without"]


def test_several_inputs_need_an_output_folder_and_a_mosaic_needs_several(pieces, tmp_path, capsys):
    whole, paths = pieces
    code, _, err = run_cli(capsys, "dtm", *paths, "-o", tmp_path / "d.tif")
    assert code == 2 and "2 inputs need an existing output folder" in error_line(err)
    code, _, err = run_cli(capsys, "dtm", whole, "-o", tmp_path / "d.tif", "--mosaic", tmp_path / "m.vrt")
    assert code == 2 and "--mosaic" in error_line(err)
    assert not (tmp_path / "d.tif").exists()
