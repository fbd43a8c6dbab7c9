"""`gfjax demo`: filter the shipped sample with the default method; no arguments, no network.

Reads ISPRS reference sample 12 (shipped in `gfjax/data`, CC BY 4.0, see its README), runs the
method `gfjax filter` runs without `--method` (`gfjax.methods.DEFAULT_METHOD`: the vote of
SMRF, MASF and PMF) with its defaults, and writes into `./gfjax-demo/` (or `--out DIR`):

- `samp12-vote.laz`: the sample with ground = class 2 (every other dimension unchanged);
- `samp12-dtm.tif`: the DTM (1 m cell means of the ground points, TIN-filled), EPSG:32632;
- `samp12-demo.png`: the classification in plan view beside the hillshaded DTM.

It prints the accuracy against the sample's own hand-made labels and the paths written. Files
of an earlier run are overwritten only with `--force`.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from gfjax.errors import InputError

DEFAULT_OUT = "gfjax-demo"
GROUND_RGB = (0.62, 0.45, 0.26)        # brown
OBJECT_RGB = (0.16, 0.55, 0.23)        # green


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("demo", help="filter the embedded sample (no arguments, no network)",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                        help=f"output folder, created if missing (default ./{DEFAULT_OUT})")
    parser.add_argument("--force", action="store_true", help="overwrite the files of an earlier run")
    return parser


def _output_folder(text: str) -> Path:
    out = Path(text)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: {out} exists and is not a folder")
    if not out.exists():
        if not out.parent.is_dir():
            raise InputError(f"--out: parent folder {out.parent} does not exist")
        out.mkdir()
    return out


def plot_demo(path: Path, cloud, ground, dtm, *, title: str, method: str) -> None:
    """Plan view of the points coloured ground / non-ground by `method` beside the hillshaded DTM (PNG)."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch
    from scipy import ndimage

    from gfjax.io.atomic import atomic_output

    xyz = cloud.xyz
    x0, y0 = np.floor(xyz[:, 0].min()), np.floor(xyz[:, 1].min())
    fig = Figure(figsize=(10.5, 7.0), layout="constrained")
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2, sharex=True, sharey=True)
    # Seen from above: each cell takes the class of its highest point; an empty cell that of
    # the nearest filled cell within 2 cells (white beyond).
    view_cell = dtm.cell
    col = np.floor((xyz[:, 0] - x0) / view_cell).astype(np.int64)
    row_s = np.floor((xyz[:, 1] - y0) / view_cell).astype(np.int64)
    h_v, w_v = int(row_s.max()) + 1, int(col.max()) + 1
    image = np.ones((h_v, w_v, 3))
    order = np.argsort(xyz[:, 2])                                      # the highest point wins
    colours = np.where(ground[order, None], np.array(GROUND_RGB), np.array(OBJECT_RGB))
    image[h_v - 1 - row_s[order], col[order]] = colours
    empty = np.ones((h_v, w_v), bool)
    empty[h_v - 1 - row_s, col] = False
    distance, (near_r, near_c) = ndimage.distance_transform_edt(empty, return_indices=True)
    image = np.where((distance <= 2)[:, :, None], image[near_r, near_c], 1.0)
    left.imshow(image, extent=(0, w_v * view_cell, 0, h_v * view_cell), interpolation="nearest")
    left.legend(handles=[Patch(color=GROUND_RGB, label="ground"), Patch(color=OBJECT_RGB, label="non-ground")],
                loc="upper right", fontsize=9)
    left.set_title(f"{method} classification")
    h, w = dtm.shape
    extent = (dtm.origin[0] - x0, dtm.origin[0] + w * dtm.cell - x0, dtm.origin[1] - h * dtm.cell - y0, dtm.origin[1] - y0)
    right.imshow(dtm.hillshade(), cmap="gray", vmin=0, vmax=1, extent=extent, interpolation="nearest")
    right.set_title(f"DTM hillshade ({dtm.cell:g} m)")
    for ax in (left, right):
        ax.set_aspect("equal")
        ax.set_xlabel(f"x - {x0:.0f} [m]")
    left.set_ylabel(f"y - {y0:.0f} [m]")
    fig.suptitle(title)
    with atomic_output(path, force=True) as tmp:
        fig.savefig(tmp, dpi=110, format="png", bbox_inches="tight")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    import gfjax
    from gfjax import dtm as dtm_lib
    from gfjax import methods, metrics
    from gfjax.cli import _job
    from gfjax.data import demo_sample

    out = _output_folder(args.out)
    sample = demo_sample()
    stem = sample.name.split("-")[0]
    method = methods.get(methods.DEFAULT_METHOD)
    laz_path, tif_path, png_path = (out / f"{stem}-{method.name}.laz", out / f"{stem}-dtm.tif",
                                    out / f"{stem}-demo.png")
    _job.check_outputs([("--out", path, None) for path in (laz_path, tif_path, png_path)],
                       force=args.force)
    start = time.perf_counter()
    cloud = gfjax.read(sample)
    result = method.filter(cloud)
    filtered = time.perf_counter()
    reference = cloud.classification == 2
    scores = metrics.point_metrics(result.ground, reference)

    gfjax.write(cloud.with_ground(result.ground), laz_path)
    dtm = dtm_lib.build(cloud, result.ground, cell_m=1.0)
    dtm.to_geotiff(tif_path)
    title = (f"{sample.name}: {cloud.n_points:,} points, {int(np.sum(result.ground)):,} ground; "
             f"total error {100 * scores['total_error']:.2f} % against the ISPRS labels")
    plot_demo(png_path, cloud, result.ground, dtm, title=title, method=method.name)
    done = time.perf_counter()

    print(f"gfjax demo: {method.name}, the default method, on {sample.name}, ISPRS filter-test "
          f"reference sample 12 (CC BY 4.0, Sithole & Vosselman 2004)")
    print(f"  points {cloud.n_points:,}, ground predicted {int(np.sum(result.ground)):,}, "
          f"ground in the reference {int(np.sum(reference)):,}")
    print(f"  total error {100 * scores['total_error']:.2f} %   type I {100 * scores['type1']:.2f} %   "
          f"type II {100 * scores['type2']:.2f} %   kappa {100 * scores['kappa']:.2f} %")
    print(f"  filter {filtered - start:.1f} s (JIT compile included), outputs {done - filtered:.1f} s")
    for path in (laz_path, tif_path, png_path):
        print(f"  wrote {path}")
    return 0
