"""Property: whatever bytes a LAS/LAZ header holds, `gfjax.io.las.read` either reads the file
(and every point round-trips) or raises `InputError`; nothing else, and nothing slow.

A short in-suite version of `experiments/fuzz_reader.py` (which runs for minutes).
"""
from __future__ import annotations

import struct
import time

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from reliability_files import write_las  # noqa: E402

from gfjax.errors import InputError  # noqa: E402
from gfjax.io import las as las_io  # noqa: E402


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    folder = tmp_path_factory.mktemp("seeds")
    return [write_las(folder / "a.las", n=200).read_bytes(),
            write_las(folder / "b.laz", n=200).read_bytes(),
            write_las(folder / "c.laz", n=300, version="1.2", point_format=3).read_bytes()]


_MUTATION = st.lists(st.tuples(st.integers(0, 511), st.binary(min_size=1, max_size=8)), min_size=1, max_size=3)


@settings(max_examples=60, deadline=None, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.integers(0, 2), mutations=_MUTATION)
def test_mutated_header_reads_or_raises_input_error(seeds, tmp_path, which, mutations):
    data = bytearray(seeds[which])
    for at, chunk in mutations:
        data[at:at + len(chunk)] = chunk
    path = tmp_path / ("case.las" if which == 0 else "case.laz")
    path.write_bytes(bytes(data))
    start = time.perf_counter()
    try:
        cloud = las_io.read(path, units="m")
    except InputError:
        pass
    else:
        out = tmp_path / ("out" + path.suffix)
        las_io.write(cloud, out, force=True)
        assert las_io.read(out, units="m").n_points == cloud.n_points
    assert time.perf_counter() - start < 10


@settings(max_examples=40, deadline=None, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(count=st.integers(0, 2**64 - 1))
def test_any_point_count_reads_or_raises_input_error(seeds, tmp_path, count):
    data = bytearray(seeds[1])
    struct.pack_into("<Q", data, 247, count)
    path = tmp_path / "count.laz"
    path.write_bytes(bytes(data))
    try:
        assert las_io.read(path, units="m").n_points == count == 200
    except InputError as err:
        assert str(path) in str(err)
