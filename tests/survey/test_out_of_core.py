"""Files filtered out of core: read a chunk at a time, filtered a tile window at a time,
rewritten a chunk at a time; the output equals the in-memory one, every dimension kept."""
from __future__ import annotations

import laspy
import numpy as np
import pytest
from test_survey import SMALL_TILES, town, write_grid

from gfjax import limits
from gfjax.cli.main import main
from gfjax.errors import InputError
from gfjax.io import stream

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)

TILING = ["--tile-size", str(SMALL_TILES.tile_size_m), "--buffer", str(SMALL_TILES.buffer_m)]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ooc")
    xyz, cls = town(seed=3)
    return write_grid(folder, xyz, cls)


def _same_but_classification(a, b) -> None:
    a, b = laspy.read(a), laspy.read(b)
    assert a.header.point_count == b.header.point_count
    assert [v.record_id for v in a.header.vlrs] == [v.record_id for v in b.header.vlrs]
    for name in a.point_format.dimension_names:
        if name != "classification":
            np.testing.assert_array_equal(np.asarray(a[name]), np.asarray(b[name]), err_msg=name)


@pytest.mark.parametrize("method", ["smrf", "pmf"])
def test_a_file_out_of_core_equals_the_file_in_memory(files, method, tmp_path, monkeypatch):
    *_, union = files
    monkeypatch.setattr(stream, "CHUNK_POINTS", 5_000)            # several chunks
    args = ["filter", str(union), "--method", method, *TILING, "--reset-nonground", "--preset", "fixed"]
    assert main([*args, "-o", str(tmp_path / "memory.laz")]) == 0
    assert main([*args, "-o", str(tmp_path / "disk.laz"), "--out-of-core"]) == 0
    memory, disk = laspy.read(tmp_path / "memory.laz"), laspy.read(tmp_path / "disk.laz")
    np.testing.assert_array_equal(np.asarray(disk.classification), np.asarray(memory.classification))
    assert np.any(np.asarray(disk.classification) == 2) and np.any(np.asarray(disk.classification) == 1)
    _same_but_classification(union, tmp_path / "disk.laz")
    assert not list(tmp_path.glob(".*"))                          # no temporary left


def test_a_survey_out_of_core_labels_as_the_union(files, tmp_path, monkeypatch):
    paths, members, union = files
    monkeypatch.setattr(stream, "CHUNK_POINTS", 3_000)
    # fixed values: the seams alone; with values that follow the data the guard, run on each
    # window, may differ near a window's edge (`test_survey.test_adaptive_survey_labels_...`)
    smrf = ["--method", "smrf"]
    assert main(["filter", str(union), "-o", str(tmp_path / "union.laz"), *smrf, *TILING, "--preset", "fixed"]) == 0
    (tmp_path / "out").mkdir()
    assert main(["filter", *map(str, paths), "-o", str(tmp_path / "out"), *smrf, *TILING, "--out-of-core",
                 "--preset", "fixed"]) == 0
    want = np.asarray(laspy.read(tmp_path / "union.laz").classification)
    got = np.zeros_like(want)
    for path, keep in zip(paths, members):
        got[keep] = np.asarray(laspy.read(tmp_path / "out" / path.name).classification)
        _same_but_classification(path, tmp_path / "out" / path.name)
    np.testing.assert_array_equal(got, want)
    for folder, flags in (("alone_disk", ["--out-of-core"]), ("alone_memory", [])):     # --independent
        (tmp_path / folder).mkdir()
        assert main(["filter", *map(str, paths[:2]), "-o", str(tmp_path / folder), *smrf, *TILING, "--independent",
                     *flags]) == 0
    for path in paths[:2]:
        np.testing.assert_array_equal(np.asarray(laspy.read(tmp_path / "alone_disk" / path.name).classification),
                                      np.asarray(laspy.read(tmp_path / "alone_memory" / path.name).classification))


def test_a_file_over_the_budget_goes_out_of_core_by_itself(files, tmp_path, monkeypatch, capsys):
    *_, union = files
    monkeypatch.setattr(limits, "IN_MEMORY_BYTES_PER_POINT", 1 << 40)
    assert main(["filter", str(union), "-o", str(tmp_path / "a.laz"), *TILING, "--method", "smrf"]) == 0
    assert "union.laz" in capsys.readouterr().err
    assert main(["filter", str(union), "-o", str(tmp_path / "b.laz"), *TILING, "--method", "smrf", "--out-of-core"]) == 0
    np.testing.assert_array_equal(laspy.read(tmp_path / "a.laz").classification,
                                  laspy.read(tmp_path / "b.laz").classification)
    capsys.readouterr()
    for option in (["--dtm", str(tmp_path / "d.tif")], ["--instances"]):
        assert main(["filter", str(union), "-o", str(tmp_path / "c.laz"), *option]) == 2
        assert f"{option[0]} needs the file in memory" in capsys.readouterr().err
        assert not (tmp_path / "c.laz").exists() and not (tmp_path / "d.tif").exists()


@pytest.mark.parametrize("method", ["dmf", "csf", "vote"])
def test_a_method_that_does_not_tile_runs_out_of_core_a_piece_at_a_time(files, method, tmp_path, monkeypatch,
                                                                       capsys):
    """One piece holding the whole file labels it as in memory; pieces of 50 m, each with its
    halo, label all but a few points near their edges alike; every other dimension kept."""
    *_, union = files
    args = ["filter", str(union), "--method", method]
    assert main([*args, "-o", str(tmp_path / "memory.laz")]) == 0
    assert main([*args, "-o", str(tmp_path / "one.laz"), "--out-of-core"]) == 0
    memory = np.asarray(laspy.read(tmp_path / "memory.laz").classification)
    np.testing.assert_array_equal(np.asarray(laspy.read(tmp_path / "one.laz").classification), memory)
    capsys.readouterr()
    monkeypatch.setattr(limits, "IN_MEMORY_BYTES_PER_POINT", 1 << 40)     # over the budget: pieces of 50 m
    assert main([*args, "-o", str(tmp_path / "pieces.laz")]) == 0
    assert f"filtering out of core with {method}, a piece and its halo at a time" in capsys.readouterr().err
    pieces = np.asarray(laspy.read(tmp_path / "pieces.laz").classification)
    assert np.mean(pieces == memory) >= 0.995
    assert np.any(pieces == 2) and np.any(pieces != 2)
    _same_but_classification(union, tmp_path / "pieces.laz")


def test_sparsegf_out_of_core_on_one_piece_labels_as_in_memory(files, tmp_path):
    """SparseGF's window on the survey's frame (its patch grid, SMRF's surface under it) labels
    a file its halo holds whole as the file in memory does, every other dimension kept."""
    *_, union = files
    args = ["filter", str(union), "--method", "sparsegf"]
    assert main([*args, "-o", str(tmp_path / "memory.laz")]) == 0
    assert main([*args, "-o", str(tmp_path / "one.laz"), "--out-of-core"]) == 0
    memory = np.asarray(laspy.read(tmp_path / "memory.laz").classification)
    np.testing.assert_array_equal(np.asarray(laspy.read(tmp_path / "one.laz").classification), memory)
    assert np.any(memory == 2) and np.any(memory != 2)
    _same_but_classification(union, tmp_path / "one.laz")


def test_pieces_shrink_where_a_piece_would_not_fit(tmp_path, monkeypatch):
    """A window (a piece and its halo) of one tile, smaller for a dense file under a small
    budget, never below the minimum."""
    from gfjax import survey
    from gfjax.io.cloud import Cloud
    from gfjax.survey import lattice

    xyz, cls = town(size=(60.0, 60.0))
    Cloud.from_xyz(xyz, classification=cls).las.write(tmp_path / "a.las")
    catalog = survey.index([tmp_path / "a.las"], tmp_path)
    assert lattice.pieces(catalog, 50.0) == lattice.Pieces(400.0, 50.0)
    assert lattice.pieces(catalog, 10.0, 250.0) == lattice.Pieces(230.0, 10.0)
    density = catalog.entries[0].n_points / np.prod(catalog.frame.upper_m - catalog.frame.origin_m[:2])
    monkeypatch.setattr(limits, "memory_budget_bytes", lambda: density * limits.IN_MEMORY_BYTES_PER_POINT * 300.0 ** 2)
    assert lattice.pieces(catalog, 50.0).tile_size_m == pytest.approx(200.0)
    monkeypatch.setattr(limits, "memory_budget_bytes", lambda: 1.0)
    assert lattice.pieces(catalog, 50.0).tile_size_m == lattice.MIN_PIECE_M


def test_a_truncated_file_read_in_chunks_is_refused_naming_it(files, tmp_path, monkeypatch):
    *_, union = files
    data = union.read_bytes()
    cut = tmp_path / "cut.laz"
    cut.write_bytes(data[: len(data) * 2 // 3])
    monkeypatch.setattr(stream, "CHUNK_POINTS", 2_000)
    with pytest.raises(InputError, match="cut.laz: truncated"):
        with stream.open_points(cut, trust_data=True) as points:
            for _ in points.chunks():
                pass
    assert main(["filter", str(cut), "-o", str(tmp_path / "out.laz"), "--out-of-core", "--trust-data"]) == 2
    assert not (tmp_path / "out.laz").exists()
