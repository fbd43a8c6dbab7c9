"""Small LAS/LAZ files and byte patches for the reliability catalogue.

Offsets are those of the ASPRS LAS 1.2 / 1.4 public header block.
"""
from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
from laspy.vlrs.vlrlist import VLRList

REPO = Path(__file__).resolve().parents[2]

# Public header block: (byte offset, struct format)
VERSION_MINOR = (25, "<B")
HEADER_SIZE = (94, "<H")
OFFSET_TO_POINTS = (96, "<I")
NUMBER_OF_VLRS = (100, "<I")
POINT_FORMAT = (104, "<B")
RECORD_LENGTH = (105, "<H")
LEGACY_POINT_COUNT = (107, "<I")
SCALE = {"x": (131, "<d"), "y": (139, "<d"), "z": (147, "<d")}
OFFSET = {"x": (155, "<d"), "y": (163, "<d"), "z": (171, "<d")}
MAX_X = (179, "<d")
START_OF_FIRST_EVLR = (235, "<Q")  # 1.4 only
NUMBER_OF_EVLRS = (243, "<I")      # 1.4 only
POINT_COUNT_64 = (247, "<Q")       # 1.4 only
VLR_HEADER = 54


def write_las(path: Path, *, n: int = 300, version: str = "1.4", point_format: int = 6,
              evlr: bool = False, seed: int = 0) -> Path:
    """A valid `n`-point file near UTM coordinates; LAZ (lazrs) when `path` ends in .laz."""
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500_000.0, 5_400_000.0, 0.0])
    las = laspy.LasData(header)
    rng = np.random.default_rng(seed)
    las.x = 500_000.0 + rng.uniform(0, 50, n)
    las.y = 5_400_000.0 + rng.uniform(0, 50, n)
    las.z = rng.uniform(0, 5, n)
    las.classification = rng.choice(np.array([1, 2], np.uint8), n)
    las.intensity = rng.integers(0, 1000, n).astype(np.uint16)
    if evlr:
        las.evlrs = VLRList([laspy.VLR(user_id="gfjax_test", record_id=7, description="test EVLR",
                                             record_data=b"evlr payload")])
    las.write(path, do_compress=path.suffix == ".laz")
    return path


def patch(path: Path, field: tuple[int, str], value) -> Path:
    """Overwrite one header field of `path` in place."""
    offset, fmt = field
    data = bytearray(path.read_bytes())
    struct.pack_into(fmt, data, offset, value)
    path.write_bytes(bytes(data))
    return path


def read_field(path: Path, field: tuple[int, str]):
    offset, fmt = field
    return struct.unpack_from(fmt, path.read_bytes(), offset)[0]


def set_point_count(path: Path, count: int) -> Path:
    """The header's point count (both fields of a 1.4 header), nothing else changed."""
    if read_field(path, VERSION_MINOR) >= 4:
        patch(path, POINT_COUNT_64, count)
    return patch(path, LEGACY_POINT_COUNT, count if count < 2**32 else 0)


def append_points(path: Path, extra: int, *, seed: int = 1) -> Path:
    """`extra` more point records after the data of an uncompressed file (header unchanged)."""
    las = laspy.read(path)
    more = write_las(path.with_name("more.las"), n=extra, version=str(las.header.version),
                     point_format=las.point_format.id, seed=seed)
    records = laspy.read(more).points.array.tobytes()
    more.unlink()
    with open(path, "ab") as f:
        f.write(records)
    return path


def run_gfjax(*argv, timeout: float = 120) -> subprocess.CompletedProcess:
    """`python -m gfjax.cli.main *argv` in a subprocess (for inputs that could block a process)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "gfjax.cli.main", *map(str, argv)], capture_output=True,
                          text=True, cwd=REPO, env=env, timeout=timeout)
