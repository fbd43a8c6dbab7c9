"""SMRF's surface as SparseGF inputs: SMRF's own decision, one value per point wherever it lies."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gfjax
from gfjax.io.cloud import Cloud
from gfjax.sparsegf import features as F
from gfjax.sparsegf.smrf_prior import smrf_heights


def town(seed=0, size_m=60.0):
    """Sloped ground, a 7 m building, a low outlier; xyz (n, 3) [m] and the building mask."""
    rng = np.random.default_rng(seed)
    n = int(1.5 * size_m * size_m)
    xy = rng.uniform(0, size_m, (n, 2))
    z = 100 + 0.05 * xy[:, 0] + rng.normal(0, 0.03, n)
    building = (xy[:, 0] > 20) & (xy[:, 0] < 32) & (xy[:, 1] > 10) & (xy[:, 1] < 22)
    z[building] += 7.0
    z[5] -= 20.0
    return np.column_stack([xy + [500_000.0, 5_400_000.0], z]), building


@pytest.fixture(scope="module")
def scene():
    """Two copies of the town 14 km apart (the second 30 m higher): one SMRF run each way."""
    xyz, building = town()
    cloud = np.concatenate([xyz, xyz + [10_000.0, 10_000.0, 30.0]])
    return cloud, np.concatenate([building, building]), smrf_heights(cloud)


def test_the_margin_is_smrfs_own_decision(scene):
    xyz, building, h = scene
    ground = gfjax.smrf.filter(Cloud.from_xyz(xyz), config=gfjax.smrf.Config()).ground   # the fixed values
    assert h.shape == (len(xyz), 2) and h.dtype == np.float32
    np.testing.assert_array_equal(h[:, 1] >= 0, ground)
    assert np.mean(np.abs(h[~building, 0]) < 0.3) > 0.99
    assert np.all(h[building, 0] > 6.0)                       # a roof stands 7 m over SMRF's ground
    assert h[5, 0] < -19.0                                    # the low outlier lies under it


def test_far_groups_each_get_their_own_surface(scene):
    xyz, _, h = scene
    n = len(xyz) // 2                                          # each town read off its own surface
    assert np.median(np.abs(h[:n, 0] - h[n:, 0])) < 1e-3
    assert h[n + 5, 0] < -19.0


def test_cloud_features_come_with_the_smrf_feature_set_only(scene):
    xyz, _, h = scene
    assert F.cloud_features(xyz, "xyz+tophat") is None and F.cloud_features(xyz, "xyz") is None
    got = F.cloud_features(xyz, "xyz+tophat+smrf")
    np.testing.assert_allclose(got, np.sign(h) * np.log1p(np.abs(h)), rtol=1e-6)
    assert F.n_features("xyz+tophat+smrf") == F.n_features("xyz+tophat") + F.N_SMRF_FEATURES
    assert smrf_heights(np.zeros((0, 3))).shape == (0, 2)


def test_cloud_features_do_not_depend_on_numpys_cpu_dispatch(tmp_path):
    """numpy picks its float32 log1p by CPU (another routine with AVX-512, 1-2 ulp apart): the
    inputs a model trains on are the same on a machine without those routines."""
    h = np.random.default_rng(0).laplace(0.0, 3.0, (50_000, 2)).astype(np.float32)
    np.save(tmp_path / "h.npy", h)
    code = ("import sys, numpy as np; from gfjax.sparsegf import features as F; "
            "np.save(sys.argv[2], F.cloud_features(None, 'xyz+tophat+smrf', smrf=np.load(sys.argv[1])))")
    env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
           "PYTHONPATH": str(Path(F.__file__).parents[2])}
    subprocess.run([sys.executable, "-c", code, str(tmp_path / "h.npy"), str(tmp_path / "f.npy")], env=env, check=True)
    np.testing.assert_array_equal(F.cloud_features(None, "xyz+tophat+smrf", smrf=h), np.load(tmp_path / "f.npy"))


def test_a_window_laid_on_the_frame_reads_the_whole_clouds_surface_away_from_its_cut():
    # a window cut 27.3 m into the town: on its own box its lattice starts off the whole
    # cloud's cells and its values differ everywhere; laid on the whole cloud's frame, the
    # points 20 m and more from the cut read the surface the whole cloud gives them
    from gfjax.io.cloud import Frame

    xyz, _ = town(seed=3, size_m=80.0)
    frame = Frame.of(xyz)
    whole = smrf_heights(xyz)
    inside = np.flatnonzero(xyz[:, 0] - frame.origin_m[0] >= 27.3)
    far = xyz[inside, 0] - frame.origin_m[0] >= 47.3
    laid = smrf_heights(xyz[inside], frame)
    np.testing.assert_allclose(laid[far], whole[inside][far], atol=1e-4)
    own = smrf_heights(xyz[inside])
    assert np.mean(np.abs(own[far, 0] - whole[inside][far, 0]) > 1e-3) > 0.5
