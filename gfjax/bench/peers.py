"""Adapters for the peer packages `gfjax bench` compares against (SPEC sections 6, 9).

Each peer takes the points a filter uses as float64 metres `(m, 3)` (`cloud.xyz_m`) and
returns ground as bool `(m,)`, with the package's defaults, which are the published defaults
that gfjax's own SMRF and CSF also use:

- `pysmrf` (Pingel et al. 2013, PyPI `pysmrf`): cell 1 m, windows 1..18 cells (18 m), slope
  0.15, elevation threshold 0.5 m, scaler 1.25; one worker thread (its default).
- `cloth-simulation-filter` (Zhang et al. 2016, PyPI `cloth-simulation-filter`, module
  `CSF`): resolution 1 m, rigidness 3, time step 0.65, class threshold 0.5 m, 500
  iterations, slope smoothing on; OpenMP threads as the environment sets them.

The peers are the optional extra `pip install -e '.[bench]'`; `installed` tells whether one
can be imported, without importing it.
"""
from __future__ import annotations

import importlib
import importlib.util
import warnings
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from gfjax.errors import InputError


class Peer(NamedTuple):
    """A peer package: its PyPI name, its import name, and how to run it."""

    name: str                                   # PyPI distribution name, used on the command line
    module: str                                 # import name
    run: Callable[[np.ndarray], np.ndarray]     # xyz metres (m, 3) float64 -> ground bool (m,)
    describes: str                              # one line: algorithm and parameters


def _run_pysmrf(xyz_m: np.ndarray) -> np.ndarray:
    pysmrf = importlib.import_module("pysmrf")
    with warnings.catch_warnings():   # pysmrf 1.0.2 multiplies affine transforms with `*`
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        warnings.simplefilter("ignore", DeprecationWarning)
        result = pysmrf.classify(xyz_m[:, 0], xyz_m[:, 1], xyz_m[:, 2], cellsize=1.0, windows=18,
                                 slope_threshold=0.15, elevation_threshold=0.5, elevation_scaler=1.25)
    return np.asarray(result.is_ground, dtype=bool)


def _run_csf(xyz_m: np.ndarray) -> np.ndarray:
    csf_module = importlib.import_module("CSF")
    cloth = csf_module.CSF()
    cloth.params.bSloopSmooth = True          # the package's spelling
    cloth.params.cloth_resolution = 1.0
    cloth.params.rigidness = 3
    cloth.params.time_step = 0.65
    cloth.params.class_threshold = 0.5
    cloth.params.interations = 500            # the package's spelling
    cloth.setPointCloud(np.ascontiguousarray(xyz_m, dtype=np.float64))
    ground, off_ground = csf_module.VecInt(), csf_module.VecInt()
    cloth.do_filtering(ground, off_ground, False)
    labels = np.zeros(len(xyz_m), dtype=bool)
    labels[np.asarray(ground, dtype=np.int64)] = True
    return labels


PEERS: dict[str, Peer] = {
    "cloth-simulation-filter": Peer("cloth-simulation-filter", "CSF", _run_csf,
                                    "CSF, 1 m cloth, rigidness 3, dt 0.65, 0.5 m, 500 iterations, smoothing"),
    "pysmrf": Peer("pysmrf", "pysmrf", _run_pysmrf,
                   "SMRF, 1 m cells, 18 m window, slope 0.15, 0.5 m + 1.25 x slope"),
}


def installed(name: str) -> bool:
    """True when peer `name`'s module can be imported (it is not imported here)."""
    module = PEERS[name].module
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):   # a parent package missing, or sys.modules[module] is None
        return False


def parse_peers(text: str | None) -> list[str]:
    """`--peers` value -> peer names: None = all known peers, "none" = no peer.

    Raises:
      InputError: an unknown peer name (the CLI exits with code 2).
    """
    if text is None:
        return list(PEERS)
    names = [part.strip() for part in text.split(",") if part.strip()]
    if names == ["none"]:
        return []
    for name in names:
        if name not in PEERS:
            raise InputError(f"--peers: unknown peer {name!r}; choose from {', '.join(PEERS)} (or none)")
    return list(dict.fromkeys(names))


def skip_note(name: str) -> str:
    """The one line printed for a peer that is not installed."""
    return (f"peer {name} skipped: not installed (pip install {name}, "
            f"or pip install -e '.[bench]' for all peers)")


__all__ = ["Peer", "PEERS", "installed", "parse_peers", "skip_note"]
