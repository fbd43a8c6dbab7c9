"""Hashes of the shipped SparseGF recipe's training inputs (20 files and their thinned copies: points,
labels, HAG bins, SMRF's prior) and of every step of its epoch 1, at the checkout on PYTHONPATH.

Run from a checkout: `PYTHONPATH=. python experiments/sparsegf_repro_hashes.py OUT.json 100000`
(about 25 min on 2 shared cores); compare two OUT.json of two commits or machines.
"""
import hashlib
import json
import sys
import time

import numpy as np

D = "../shared/data"
REF = f"{D}/isprs_filtertest/reference"
C = f"{D}/corpus"
FILES = [f"{REF}/samp{s}-utm.laz" for s in (12, 21, 24, 41, 51, 52, 71)] + [
    f"{D}/lasR_bcts/bcts_1.laz", f"{D}/lidR_topography/Topography.laz", f"{D}/pdal_autzen/autzen_trim.laz",
    f"{C}/brycefrank_pyfor/test.laz", f"{C}/PDAL_PDAL/hexbin-crop.las", f"{C}/PDAL_PDAL/4_6_crop.las",
    f"{C}/IGNF_ign-pdal-tools/las_with_several_extra_byte_bloc.laz",
    f"{C}/IGNF_ign-pdal-tools/test_semis_2023_0292_6833_LA93_IGN69.laz",
    f"{C}/IGNF_ign-pdal-tools/test_semis_2021_0382_6565_LA93_IGN69_cropped.laz",
    f"{C}/IGNF_ign-pdal-tools/Semis_2022_0906_6665_LA93_IGN69_ok.laz",
    f"{C}/IGNF_lidar-prod/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz",
    f"{C}/tudelft3d_3dfier/ahn3_cropped_1.laz", f"{C}/eEcoLiDAR_laserchicken/AHN3.laz"]


def h(a):
    a = np.ascontiguousarray(np.asarray(a))
    return hashlib.sha256(a.tobytes() + str(a.dtype).encode() + str(a.shape).encode()).hexdigest()[:16]


def main(out, steps_wanted):
    from gfjax import adaptive
    from gfjax.cli.train import _load
    from gfjax.sparsegf import train
    from gfjax.sparsegf.config import Config
    from gfjax.sparsegf.features import cloud_features

    t0 = time.time()
    config = Config(features="xyz+tophat+smrf")
    clouds = _load(FILES, None, 2)
    data = [train.labelled_cloud(c, config) for c in clouds]
    data += train.thinned(clouds, config, copies=1, seed=0)
    res = {"clouds": [], "steps": []}
    names = [f.rsplit("/", 1)[1] for f in FILES]
    names += [f"thin:{n}" for n, d in zip(names, data) if 1.0 / adaptive.measure(d.xyz_m).spacing_m ** 2 > 0.2]
    for name, d in zip(names, data):
        t = time.time()
        feats = cloud_features(d.xyz_m, config.features)
        res["clouds"].append(dict(name=name, n=len(d.xyz_m), density=1.0 / adaptive.measure(d.xyz_m).spacing_m ** 2,
                                  xyz=h(d.xyz_m), ground=h(d.ground), hag=h(d.hag_bin), feats=h(feats),
                                  smrf_cols=h(feats[:, -2:]) if feats is not None else None, s=round(time.time() - t, 1)))
        print(res["clouds"][-1], flush=True)
        data[names.index(name)] = d._replace(cloud_feats=feats)
    rng = np.random.default_rng([0, 0])
    for i, step in enumerate(train.training_batches(data, config, batch_size=4, rng=rng, plans={},
                                                    min_patches=30, max_patches=40)):
        p = step.packed
        res["steps"].append(dict(i=i, patches=len(p.patches), coords=h(p.coords), feats=h(p.feats), valid=h(p.valid),
                                 weight=h(p.weight), point_row=h(p.point_row), point_feats=h(p.point_feats),
                                 labels=h(step.labels), bins=h(step.bins)))
        if i < 3 or i % 50 == 0:
            print(res["steps"][-1], flush=True)
        if i + 1 >= steps_wanted:
            break
    res["rng_after"] = int(rng.integers(1 << 62)) if len(res["steps"]) < steps_wanted else None
    res["seconds"] = time.time() - t0
    json.dump(res, open(out, "w"), indent=1)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))
