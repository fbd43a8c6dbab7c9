"""A file's point records kept uncompressed: the cloud and the copy made from them equal the file's."""
from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np

from gfjax.io import las as las_io
from gfjax.io import point_store, stream
from gfjax.io.cloud import Cloud


def _file(path, n=5_000, seed=0):
    """A LAS 1.4 file of point format 7 with an extra-bytes dimension and an EVLR."""
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.uniform(0, 100, n), rng.uniform(0, 80, n), rng.normal(50, 3, n)])
    las = Cloud.from_xyz(xyz, point_format=7).las
    las.add_extra_dim(laspy.ExtraBytesParams(name="echo_width", type=np.float32))
    las.echo_width = rng.uniform(0, 4, n).astype(np.float32)
    las.intensity = rng.integers(0, 60_000, n).astype(np.uint16)
    las.classification = rng.choice([1, 2, 6, 7], n).astype(np.uint8)
    las.evlrs = laspy.vlrs.vlrlist.VLRList([laspy.VLR("gfjax_test", 7, "an EVLR", b"kept")])
    las.write(path)
    return path


def _kept(path, folder) -> Path:
    """`path`'s records written to a store a chunk at a time, as a survey's catalog does."""
    target = folder / "points.npy"
    with stream.open_points(path) as points, point_store.Writer(target, points.header.point_format.dtype(),
                                                                points.n_points) as out:
        for _, chunk in points.chunks(size=1_000):
            out.append(chunk.array)
    return target


def test_blocks_and_load_give_the_records_written(tmp_path):
    path = _file(tmp_path / "a.laz")
    kept = _kept(path, tmp_path)
    want = laspy.read(path).points.array
    np.testing.assert_array_equal(point_store.load(kept), want)
    starts, parts = zip(*point_store.blocks(kept, 1_500))
    assert starts == (0, 1_500, 3_000, 4_500)
    np.testing.assert_array_equal(np.concatenate(parts), want)


def test_a_cloud_read_from_the_store_equals_the_file_read(tmp_path):
    path = _file(tmp_path / "a.laz")
    kept = _kept(path, tmp_path)
    read, stored = las_io.read(path), las_io.read(path, stored=kept)
    np.testing.assert_array_equal(stored.las.points.array, read.las.points.array)
    np.testing.assert_array_equal(stored.xyz_m, read.xyz_m)
    assert [v.record_data for v in stored.las.evlrs] == [b"kept"]
    assert (stored.horizontal_unit_m, stored.crs) == (read.horizontal_unit_m, read.crs)


def test_a_copy_relabelled_from_the_store_is_the_copy_from_the_file(tmp_path):
    path = _file(tmp_path / "a.laz")
    kept = _kept(path, tmp_path)
    ground = np.random.default_rng(1).random(5_000) < 0.3
    for suffix in (".laz", ".las"):
        a, b = tmp_path / f"from_file{suffix}", tmp_path / f"from_store{suffix}"
        counts = stream.relabel(path, a, ground)
        assert stream.relabel(path, b, ground, stored=kept) == counts
        assert a.read_bytes() == b.read_bytes()
