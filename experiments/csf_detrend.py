"""CSF on the cloud less its trend: a trial (not a default).

The cloth of rigidness 3 cannot follow the ISPRS samples' slopes. Here the cloud's 30 m trend
(the minimum surface on the slope grid of `gfjax.adaptive`, 10th-percentile erosion, optionally
dilated back ("open"), smoothed) is taken off before CSF runs; the labels are scored against the
file's own ground. Usage:

    nice .venv/bin/python experiments/csf_detrend.py samp12,samp24,samp31 none:3,open:1

a candidate is `trend:rigidness[:cell_m:class_threshold_m]`, trend one of none, erode, open.
Prints total error / type I / type II / DTM RMSE per file and candidate.
"""
import math
import sys
import time

import numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
from scipy import ndimage
import gfjax
from gfjax import adaptive, metrics, csf
from gfjax.io.cloud import Cloud
from experiments.common import LABELLED

def trend(xyz, t, mode):
    cell = t.slope_cell_m
    index, shape = adaptive._cells(xyz[:, :2], cell)
    zmin = np.full(shape[0] * shape[1], np.inf); np.minimum.at(zmin, index, xyz[:, 2]); zmin = zmin.reshape(shape)
    filled = np.isfinite(zmin)
    idx = ndimage.distance_transform_edt(~filled, return_distances=False, return_indices=True)
    zf = zmin[tuple(idx)]
    size = max(3, 2 * math.ceil(30.0 / (2 * cell)) + 1)
    er = ndimage.percentile_filter(zf, 10, size=size, mode="nearest")
    if mode == "open":
        er = ndimage.grey_dilation(er, size=size, mode="nearest")
    sm = ndimage.uniform_filter(er, size=size, mode="nearest")
    lo = xyz[:, :2].min(0)
    rc = (xyz[:, 1] - lo[1]) / cell - 0.5, (xyz[:, 0] - lo[0]) / cell - 0.5
    return ndimage.map_coordinates(sm, [rc[0], rc[1]], order=1, mode="nearest")

names = sys.argv[1].split(",")
cands = sys.argv[2].split(",")
for e in LABELLED:
    if e.name not in names: continue
    cloud = gfjax.read(e.file)
    xyz = cloud.xyz_m
    t = adaptive.measure(xyz[cloud.filter_mask("all")], xyz[cloud.filter_mask("last")])
    ref = cloud.classification == 2; sc = metrics.scored_mask(cloud.classification)
    out = []
    for c in cands:
        mode, rig, cell, thr = (c.split(":") + ["1", "0.5"])[:4] if c.count(":") == 1 else c.split(":")
        if mode == "none":
            run_cloud = cloud
        else:
            x2 = xyz.copy(); x2[:, 2] -= trend(xyz, t, mode)
            run_cloud = Cloud.from_xyz(x2, scale=0.001)
        cfg = csf.Config(rigidness=int(rig), cell_m=float(cell)); prm = csf.Params(class_threshold_m=float(thr))
        t0 = time.time()
        g = np.asarray(csf.filter(run_cloud, config=cfg, params=prm, progress=False).ground, bool)
        p = metrics.point_metrics(g, ref, mask=sc); d = metrics.dtm_metrics(xyz, g, ref, cell_m=2.0, mask=sc)
        ok = p["type1"] <= .1 and d["rmse_m"] <= .3
        out.append(f"{c}: {100*p['total_error']:.1f}/{100*p['type1']:.1f}/{100*p['type2']:.1f}/{d['rmse_m']:.2f}{'' if ok else ' FAIL'}")
    print(f"{e.name:10s} p90 {t.slope_p90:.2f} | " + " | ".join(out), flush=True)
