"""Per training file: points training sees vs points SparseGF's filter sees (ignored classes, hidden
low outliers), and how SMRF's prior (the network's per-cloud inputs) changes on the points both see."""
import json
import sys
import time

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
from sparsegf_repro_hashes import FILES, REF

from gfjax import adaptive
from gfjax.io import las as las_io
from gfjax.sparsegf.smrf_prior import smrf_heights

rows = []
for path in FILES + [f"{REF}/samp31-utm.laz"]:
    t = time.time()
    cloud = las_io.read(path)
    xyz = cloud.xyz_m
    used = cloud.filter_mask("all")
    terrain = adaptive.measure(xyz[used], xyz[cloud.filter_mask("last")])
    hidden = adaptive.hide(cloud, terrain)
    hidden = np.zeros(len(xyz), bool) if hidden is None else hidden
    seen = used & ~hidden
    row = dict(file=path.rsplit("/", 1)[1], n=len(xyz), ignored=int((~used).sum()), hidden=int(hidden.sum()),
               hidden_ground=int((hidden & (cloud.classification == 2)).sum()))
    if (~seen).any():
        full = smrf_heights(xyz)
        for tag, mask in (("ignored_only", used), ("head", seen)):
            if tag == "ignored_only" and not (~used).any():
                continue
            h = smrf_heights(xyz[mask])
            sub = full[mask]
            d = np.abs(h[:, 0] - sub[:, 0])
            row[tag] = dict(points=int(mask.sum()), dz_changed=int((h[:, 0] != sub[:, 0]).sum()),
                            dz_changed_over_1cm=int((d > 0.01).sum()), dz_max_change_m=float(d.max()),
                            margin_changed=int((h[:, 1] != sub[:, 1]).sum()),
                            verdict_flipped=int(((h[:, 1] >= 0) != (sub[:, 1] >= 0)).sum()))
    row["s"] = round(time.time() - t, 1)
    print(json.dumps(row), flush=True)
    rows.append(row)
json.dump(rows, open(sys.argv[1], "w"), indent=1)
