"""What the ISPRS accuracy experiments share: the sample files, a first-and-warm call, scoring.

    from experiments.common import ISPRS_REFERENCE, isprs_samples, first_and_again, score
    for path in isprs_samples():
        cloud = gfjax.read(path)
        first_s, again_s, result = first_and_again(lambda: gfjax.smrf.filter(cloud))
        m = score(result.ground, cloud)

The labelled data are not shipped (docs/development.md, "Data": where each file comes from and how to get
it): they are read from `$GFJAX_SHARED_DATA`, by default `../shared/data` beside the
repository. ISPRS reference ground is ASPRS class 2, every other class non-ground.
Scores are those of `gfjax.metrics.point_metrics` (SPEC section 8).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

from gfjax.bench.harness import Stopwatch, time_call
from gfjax.io.cloud import Cloud
from gfjax.metrics import point_metrics

__all__ = ["ROOT", "DATA", "ISPRS_REFERENCE", "RESULTS", "KEYS", "Labelled", "LABELLED", "isprs_samples",
           "labelled", "files_parser", "first_and_again", "median_time", "score", "write_json", "write_markdown"]

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data"))
ISPRS_REFERENCE = DATA / "isprs_filtertest" / "reference"
RESULTS = ROOT / "experiments" / "results"
KEYS = ("total_error", "type1", "type2", "kappa")        # the per-sample scores the tables report

T = TypeVar("T")


@dataclasses.dataclass(frozen=True)
class Labelled:
    """One labelled file of `../shared/data` and how it may be used.

    Attributes:
      path: relative to `DATA`.
      name: short name in tables.
      survey: the survey (or vendor) it comes from: leave-one-survey-out holds these out together.
      terrain: a few words.
      split: "train" (may fit weights and thresholds that ship), "test" (never fitted on, never
        used to choose: the held-out figure of `corpus_eval`), or "eval" (may be scored and
        used for validation, never for anything that ships: `corpus/README.md`'s *eval only*).
    """

    path: str
    name: str
    survey: str
    terrain: str
    split: str

    @property
    def file(self) -> Path:
        return DATA / self.path


_ISPRS_TEST = (22, 42, 54)
_CORPUS = "corpus/"
# The 29 labelled files: the 11 ISPRS reference samples, BCTS, Topography, autzen, and the 14
# vendor-classified corpus tiles. Test files: never trained on, never used to pick a value.
LABELLED: tuple[Labelled, ...] = (
    *(Labelled(f"isprs_filtertest/reference/samp{k}-utm.laz", f"samp{k}", f"isprs{k // 10}",
               "ISPRS " + ("urban" if k < 40 else "rural/forest"), "test" if k in _ISPRS_TEST else "train")
      for k in (12, 21, 22, 24, 31, 41, 42, 51, 52, 54, 71)),
    Labelled("lasR_bcts/bcts_1.laz", "bcts_1", "bcts", "conifer forest, slopes", "train"),
    Labelled("lasR_bcts/bcts_2.laz", "bcts_2", "bcts", "conifer forest, slopes", "test"),
    Labelled("lidR_topography/Topography.laz", "Topography", "topography", "forest, relief, lake", "train"),
    Labelled("pdal_autzen/autzen_trim.laz", "autzen", "autzen", "suburb, feet", "train"),
    Labelled(_CORPUS + "brycefrank_pyfor/test.laz", "pyfor_test", "pyfor", "flat forest, understory", "train"),
    Labelled(_CORPUS + "PDAL_PDAL/hexbin-crop.las", "hexbin", "pdal_hexbin", "high mountains, sparse", "train"),
    Labelled(_CORPUS + "PDAL_PDAL/4_6_crop.las", "4_6_crop", "pdal_4_6", "semi-arid plot, feet", "train"),
    Labelled(_CORPUS + "IGNF_ign-pdal-tools/las_with_several_extra_byte_bloc.laz", "ign_fields", "ign",
             "flat fields", "train"),
    Labelled(_CORPUS + "IGNF_ign-pdal-tools/test_semis_2023_0292_6833_LA93_IGN69.laz", "ign_2023", "ign",
             "rural + village, thinned", "train"),
    Labelled(_CORPUS + "IGNF_ign-pdal-tools/test_semis_2021_0382_6565_LA93_IGN69_cropped.laz", "ign_2021", "ign",
             "rural + village, thinned", "train"),
    Labelled(_CORPUS + "IGNF_ign-pdal-tools/Semis_2022_0906_6665_LA93_IGN69_ok.laz", "ign_forest", "ign",
             "forest, 0.1 pts/m2", "train"),
    Labelled(_CORPUS + "IGNF_ign-pdal-tools/test_data_77050_627755_LA93_IGN69.laz", "ign_city", "ign",
             "dense city block", "test"),
    Labelled(_CORPUS + "IGNF_lidar-prod/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz", "st_barth",
             "ign_st_barth", "island town", "train"),
    Labelled(_CORPUS + "LAStools_LAStools/fusa.laz", "fusa", "lastools", "suburb", "test"),
    Labelled(_CORPUS + "tudelft3d_3dfier/ahn3_cropped_1.laz", "ahn3_delft", "ahn3", "city, canals", "train"),
    Labelled(_CORPUS + "eEcoLiDAR_laserchicken/AHN3.laz", "ahn3_water", "ahn3", "water-dominated", "train"),
    Labelled(_CORPUS + "SDFIdk_DHMQC/1km_6076_548.laz", "dk_rural", "dk", "Danish rural", "test"),
    Labelled(_CORPUS + "cran_lidaRtRee/las_chablais3.laz", "chablais3", "chablais", "steep Alpine forest", "test"),
)


def labelled(split: str | None = None) -> list[Labelled]:
    """The files of `LABELLED` present under `DATA` (all, or those of one `split`)."""
    return [f for f in LABELLED if f.file.exists() and (split is None or f.split == split)]


def isprs_samples(folder: Path = ISPRS_REFERENCE) -> list[Path]:
    """The ISPRS reference samples `samp*-utm.laz` of `folder`, sorted (11 in the shared data;
    an empty list when the folder is absent)."""
    return sorted(Path(folder).glob("samp*-utm.laz"))


def files_parser(doc: str, default_files: list[Path], json_name: str) -> argparse.ArgumentParser:
    """The command line of a per-file experiment: `[FILES...] [--json OUT]`, described by the
    first line of `doc`, OUT defaulting to `experiments/results/<json_name>`."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path, default=default_files)
    parser.add_argument("--json", type=Path, default=RESULTS / json_name)
    return parser


def write_json(path: Path, environment: dict, summary: dict, rows: list[dict]) -> None:
    """Write `{"environment", "summary", "files"}` as indented JSON to `path` (folders made)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"environment": environment, "summary": summary, "files": rows}, indent=1))


def write_markdown(path: Path, lines: list[str]) -> None:
    """Write a results report (one line per item) to `path` (folders made) and say so."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path}")


def first_and_again(fn: Callable[[], T]) -> tuple[float, float, T, T]:
    """Call `fn` twice: `(first_s, again_s, first, again)`, wall-clock seconds of each call
    (`gfjax.bench.harness.Stopwatch`); the first includes JIT compilation, the second runs warm."""
    with Stopwatch() as first_watch:
        first = fn()
    with Stopwatch() as again_watch:
        again = fn()
    return first_watch.wall_s, again_watch.wall_s, first, again


def score(ground: np.ndarray, cloud: Cloud, mask: np.ndarray | None = None) -> dict:
    """`point_metrics` of bool `(n,)` ground labels against the cloud's class 2, on `mask`
    (bool `(n,)`, default all points)."""
    return point_metrics(ground, cloud.classification == 2, mask=mask)


def median_time(fn: Callable, *args, repeats: int) -> float:
    """Median wall time [s] of `repeats` calls `fn(*args)` after one warm-up call (compiles
    apart), each waited for (`jax.block_until_ready`): `gfjax.bench.harness.time_call`."""
    timing, _ = time_call(lambda: fn(*args), repeat=repeats, warmup=1, block=True)
    return float(timing.median_s)
