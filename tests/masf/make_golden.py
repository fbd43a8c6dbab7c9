"""Regenerate `golden_town.npz` (MASF labels of the synthetic town, default settings).

Run from the repository root: `.venv/bin/python tests/masf/make_golden.py`. Only regenerate
after a deliberate change of the method, and say why in the commit message.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from scene import town  # noqa: E402

from gfjax import masf  # noqa: E402
from gfjax.io.cloud import Cloud  # noqa: E402

if __name__ == "__main__":
    xyz, _, _ = town()
    result = masf.filter(Cloud.from_xyz(xyz))
    np.savez_compressed(Path(__file__).with_name("golden_town.npz"), ground=result.ground,
                        layer_sizes=result.diagnostics.layers.sum(axis=1))
    print("ground", int(result.ground.sum()), "of", len(xyz))
