"""Where MASF's errors come from on a labelled file: which stage loses each missed ground point.

    nice .venv/bin/python experiments/masf_diagnose.py samp41 samp52 samp24 [--set key=value ...]

Runs MASF as its defaults do (low outliers hidden, the spike guard after) and sorts every
reference ground point labelled non-ground (type I) and every non-ground point labelled ground
(type II) by the stage that decided it: hidden as a low outlier, not a potential ground point
(another point of its 1 m cell chosen), a potential ground point in no layer of the pyramid, in
a layer but rejected by the densification, dropped by the spike guard. For the missed ground
it also gives the vertical offset from the final TIN (above or below) and the slope of the
reference ground TIN under it. Training files only when choosing anything.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gfjax  # noqa: E402
from experiments.common import LABELLED  # noqa: E402
from gfjax import adaptive, metrics  # noqa: E402
from gfjax.masf import config as masf_config  # noqa: E402
from gfjax.masf import densify as densify_mod  # noqa: E402
from gfjax.masf.ground_tin import GroundTin  # noqa: E402
from gfjax.masf.tin import nearest_z  # noqa: E402

masf_filter = importlib.import_module("gfjax.masf.filter")     # the module, not `gfjax.masf.filter` the function


def _value(text: str):
    if text in ("None", "none"):
        return None
    if text in ("True", "False"):
        return text == "True"
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text


def diagnose(name: str, overrides: dict) -> dict:
    entry = {e.name: e for e in LABELLED}[name]
    cloud = gfjax.read(entry.file)
    cfg_fields = {f for f in masf_config.Config.__dataclass_fields__}
    cfg = masf_config.Config(**{k: v for k, v in overrides.items() if k in cfg_fields})
    par = masf_config.Params(**{k: v for k, v in overrides.items() if k not in cfg_fields})
    settled = adaptive.settle_cloud(masf_config.adapt, cloud, cfg, par, fixed=list(overrides))
    cfg, par = settled.config, settled.params
    low = adaptive.hide(cloud, settled.terrain)
    low = np.zeros(cloud.n_points, bool) if low is None else low
    used = cloud.filter_mask("all") & ~low
    idx = np.flatnonzero(used)
    prep = masf_filter.prepare(cloud.xyz_m[idx], cfg, cloud.frame)
    layers = masf_filter.pyramid(prep, cfg)
    dens = masf_filter.densify(prep, layers, cfg, par)
    ground_used = dens.ground
    raw = np.zeros(cloud.n_points, bool)
    raw[idx] = ground_used
    view = adaptive.Hidden(cloud, low) if low.any() else cloud
    from gfjax import spikes
    final = spikes.guard(cloud.xyz_m, view.filter_mask("all"), raw, spacing_m=settled.terrain.spacing_m,
                         slope_p90=settled.terrain.slope_p90)

    ref = cloud.classification == 2
    scored = metrics.scored_mask(cloud.classification)
    m = metrics.point_metrics(final, ref, mask=scored)
    # stage of each point
    n = cloud.n_points
    stage = np.full(n, "unused", dtype=object)
    stage[low] = "low outlier"
    stage[idx] = "not potential ground"
    seeds = idx[prep.pre.index]
    stage[seeds] = "potential, in no layer"
    in_layer = layers.any(axis=0)
    first = np.where(in_layer, np.argmax(layers, axis=0), -1)
    stage[seeds[in_layer]] = "potential, layer rejected"
    stage[seeds[dens.seed_ground]] = "joined TIN"
    top = np.zeros(n, bool)
    top[seeds[layers[0]]] = True
    # final TIN offsets
    seed_xyz = prep.seed_xyz
    ring_xy = densify_mod.buffer_cells(prep.pre.shape, cell_m=cfg.grid_m)
    ring = np.column_stack([ring_xy, nearest_z(ring_xy, seed_xyz[dens.seed_ground])])
    tin = GroundTin(np.concatenate([seed_xyz[dens.seed_ground], ring]))
    if cfg.buffer_heights != "top":
        ids = int(dens.seed_ground.sum()) + np.arange(len(ring))
        tin = tin.with_heights(ids, densify_mod.buffer_z(tin, ids, extrapolate=cfg.buffer_heights == "extrapolated"))
    local = cloud.xyz_m - prep.origin
    dist, facet = tin.measure(local)
    # signed vertical offset from the TIN under the point
    corners = tin.xyz_m[tin.simplices[np.maximum(facet, 0)]]
    nrm = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    zt = corners[:, 0, 2] - (nrm[:, 0] * (local[:, 0] - corners[:, 0, 0]) + nrm[:, 1] * (local[:, 1] - corners[:, 0, 1])) / nrm[:, 2]
    offset = local[:, 2] - zt
    # reference slope: TIN of reference ground
    rtin = GroundTin(local[ref & scored])
    _, rf = rtin.measure(local)
    rc = rtin.xyz_m[rtin.simplices[np.maximum(rf, 0)]]
    rn = np.cross(rc[:, 1] - rc[:, 0], rc[:, 2] - rc[:, 0])
    rn /= np.linalg.norm(rn, axis=1, keepdims=True)
    slope = np.where(rf >= 0, np.hypot(rn[:, 0], rn[:, 1]) / np.maximum(np.abs(rn[:, 2]), 1e-9), np.nan)

    type1 = ref & ~final & scored
    type2 = ~ref & final & scored
    guard = raw & ~final
    print(f"\n== {name}: TE {100 * m['total_error']:.2f} % type I {100 * m['type1']:.2f} % type II "
          f"{100 * m['type2']:.2f} %; ground {int((ref & scored).sum())}, non-ground {int((~ref & scored).sum())}; "
          f"settled {settled.chosen}")
    print(f"   potential ground {len(seeds)}, layers {layers.sum(axis=1).tolist()}, added {dens.added_per_layer.tolist()}")
    print(f"   top layer: {int(top.sum())} points, of them non-ground {int((top & ~ref).sum())}")
    for label, mask in (("type I", type1), ("type II", type2)):
        print(f"   {label}: {int(mask.sum())}")
        for s in ("low outlier", "not potential ground", "potential, in no layer", "potential, layer rejected",
                  "joined TIN"):
            sel = mask & (stage == s)
            if label == "type I" and s != "low outlier":
                off = offset[sel]
                print(f"      {s:28s} {int(sel.sum()):6d}  guard {int((sel & guard).sum()):5d}  "
                      f"above TIN {int((off > 0).sum()):5d} below {int((off <= 0).sum()):5d}  "
                      f"|offset| median {np.nanmedian(np.abs(off)) if sel.any() else float('nan'):.2f} m  "
                      f"ref slope median {np.nanmedian(slope[sel]) if sel.any() else float('nan'):.2f}")
            else:
                print(f"      {s:28s} {int(sel.sum()):6d}  guard {int((sel & guard).sum()):5d}")
        if label == "type I":
            off = offset[mask & ~low]
            edges = [0, 0.5, 1, 2, 5, 1e9]
            hist_above = np.histogram(off[off > 0], edges)[0]
            hist_below = np.histogram(-off[off <= 0], edges)[0]
            print(f"      offset bins {edges[:-1]}: above {hist_above.tolist()} below {hist_below.tolist()}")
            sl = slope[mask]
            print(f"      ref slope bins [0,.1,.3,.6,1,inf]: {np.histogram(sl[np.isfinite(sl)], [0, .1, .3, .6, 1, 1e9])[0].tolist()}"
                  f"  all ground: {np.histogram(slope[ref & scored][np.isfinite(slope[ref & scored])], [0, .1, .3, .6, 1, 1e9])[0].tolist()}")
    return {"cloud": cloud, "final": final, "stage": stage, "offset": offset, "slope": slope, "layers": layers,
            "seeds": seeds, "first": first, "prep": prep, "dens": dens, "ref": ref, "low": low}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--set", action="append", default=[])
    args = parser.parse_args()
    overrides = {k: _value(v) for k, v in (s.split("=", 1) for s in args.set)}
    for name in args.files:
        diagnose(name, overrides)


if __name__ == "__main__":
    main()
