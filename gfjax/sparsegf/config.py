"""SparseGF's static settings (Qin et al. 2026, Sec. 3.3), in metres."""
from __future__ import annotations

import dataclasses

from gfjax import limits
from gfjax.errors import SettingError
from gfjax.limits import Range
from gfjax.sparsegf.compress import R_IN_M, R_OC_M, R_OO_M
from gfjax.sparsegf.features import FEATURE_SETS, reads_smrf
from gfjax.sparsegf.partition import STEP_M

VOXEL_M = 0.5            # voxel edge of the sparse convolutions [m] (Sec. 3.3)
MAX_CONTEXT_POINTS = 10_000
DECISIONS = ("network", "network+smrf")
# The decision "network+smrf" (`vote.decide`): thresholds on the mean vote of the points SMRF
# calls ground and of those it calls objects. SMRF's ground stays ground unless the network is
# sure against it (a mean vote of 0.2 or less). Chosen on the 21 training files of
# `experiments/common.LABELLED`, each voted by the model trained without its survey, as a
# survey the model never saw votes (files passing, type I <= 10 % and DTM RMSE <= 0.30 m: 19
# at 0.3, 20 from 0.2 down to 0.01, the lowest mean total error at 0.2;
# `experiments/results/sparsegf_decision_out_of_fold.md`). On the votes of the files it
# trained on, the model is surer, and the same rule chose 0.05 there
# (`experiments/results/sparsegf_decision_corpus.md`).
SMRF_GROUND_PROBABILITY = 0.2
# ... and a point it rejects that lies within this of the ground kept around it is ground all
# the same [m] (a few times ALS's vertical noise; 0.05-0.1 m pass as many training files).
LEVEL_TOLERANCE_M = 0.1
SMRF_OBJECT_PROBABILITY = 0.9
# A model records the point densities it was trained on (`gfjax train`: its files' points per
# m² of covered area); a cloud denser or sparser than those by more than this factor is one
# it has not seen, and the decision "network+smrf" then gives SMRF's labels. Chosen on the
# training files (the shipped model saw 0.17-11.8 points/m²): at 2 the 0.06 points/m² IGN
# forest and the 25 points/m² St Barth tile fall outside (total error 8.7 -> 4.5 % and
# 40.8 -> 43.8 %), at 1 also the Delft tile (1.4 -> 2.6 %), at 3 none.
DENSITY_SLACK = 2.0
# A survey window's points within this of its core are voted on by every patch that votes on
# them in the whole cloud (`filter`'s `core`), so that the labels the core's read are the whole
# cloud's too: a point's 8 nearest ground points, for the level test and then the spike guard
# (8 points lie within 6.5 m at 0.06 ground points/m², the sparsest training file's density).
# Farther halo points take SMRF's verdict. Two files of bcts_2 as a survey gave the same labels
# with 0, 10 and 50 m, and 50 m cost 1.17x the time of 10 m
# (`experiments/results/survey_scale.md`) [m].
CORE_REACH_M = 20.0
# How the mean votes become labels: settings of a run, not of a network. A model file does
# not carry them (`filter.load_model`); they come from `Config`'s defaults or `--set`.
DECISION_FIELDS = ("decision", "ground_probability", "smrf_ground_probability", "smrf_object_probability")

# The valid range of every numeric Config field (`gfjax.limits`). Voxel indices are packed in
# 16 bits (`gfjax.nn.sparse.keys`): at 0.05 m a patch still spans 1.6 km of height. Patch
# centres closer than 10 m put every point in the central regions of over 50 patches (and the
# partition's grid over a survey grows as 1 / step^2) for no vote the defaults lack.
RANGES: dict[str, Range] = {
    "voxel_m": Range(0.05, 1e5, high_open=True, unit="m"),
    "step_m": Range(10, 1e5, high_open=True, unit="m"),
    "r_in_m": Range(0, 1e5, low_open=True, high_open=True, unit="m", extra="< r_oc_m"),
    "r_oc_m": Range(0, 1e5, low_open=True, high_open=True, unit="m", extra="<= r_oo_m"),
    "r_oo_m": Range(0, 1e5, low_open=True, high_open=True, unit="m"),
    "max_context_points": Range(1_000, 10_000_000, integer=True),
    "ground_probability": Range(0, 1, low_open=True, high_open=True),
    "smrf_ground_probability": Range(0, 1, low_open=True, high_open=True),
    "smrf_object_probability": Range(0, 1, low_open=True, high_open=True),
}


@dataclasses.dataclass(frozen=True)
class Config:
    """Static settings of the SparseGF pipeline.

    Attributes:
      voxel_m: voxel edge [m] (0.5; the paper's backbone-only baseline uses 1.0).
      step_m: grid step of the patch centres [m] (50).
      r_in_m, r_oc_m, r_oo_m: inner invariant, outer compressed and outer original radii [m]
        (25 sqrt 2, 44, 150).
      compression: apply the context compression (False: the ablation without it).
      features: the network's per-point inputs: `"xyz"` (the paper's coordinates),
        `"xyz+tophat"` (and the heights over eight opened minimum surfaces) or
        `"xyz+tophat+smrf"` (and the height over SMRF's ground surface and SMRF's margin,
        computed once per cloud; `gfjax.sparsegf.features`, `gfjax.sparsegf.smrf_prior`).
      max_context_points: points per patch at most (all central ones kept; the periphery
        thinned at random with a fixed seed); a CPU budget, not in the paper.
      decision: how the mean votes become labels (`vote.decide`): `"network"`, the paper's
        (Algorithm 1): ground when the mean vote exceeds `ground_probability`;
        `"network+smrf"`: the network arbitrates SMRF's verdict, a point SMRF calls ground
        is ground when its mean vote exceeds `smrf_ground_probability`, one SMRF calls an
        object when it exceeds `smrf_object_probability` (SMRF with its defaults, run once
        over the cloud: `smrf_prior`). Not in the paper: the tiny network alone misses
        much ground under forest canopy (`experiments/results/sparsegf_decision.md`).
      ground_probability: the threshold of the decision `"network"` (0.5, Algorithm 1).
      smrf_ground_probability, smrf_object_probability: the two thresholds of the decision
        `"network+smrf"`.
    """

    voxel_m: float = VOXEL_M
    step_m: float = STEP_M
    r_in_m: float = R_IN_M
    r_oc_m: float = R_OC_M
    r_oo_m: float = R_OO_M
    compression: bool = True
    features: str = "xyz+tophat+smrf"
    max_context_points: int = MAX_CONTEXT_POINTS
    decision: str = "network+smrf"
    ground_probability: float = 0.5
    smrf_ground_probability: float = SMRF_GROUND_PROBABILITY
    smrf_object_probability: float = SMRF_OBJECT_PROBABILITY

    @property
    def reads_smrf(self) -> bool:
        """Whether the inputs or the decision need SMRF's run over the cloud."""
        return reads_smrf(self.features) or self.decision == "network+smrf"

    def __post_init__(self):
        limits.check_fields(self, RANGES)
        if self.decision not in DECISIONS:
            raise SettingError(f"decision must be one of {DECISIONS}, got {self.decision!r}", "decision")
        if self.features not in FEATURE_SETS:
            raise SettingError(f"features must be one of {FEATURE_SETS}, got {self.features!r}", "features")
        if not self.r_in_m < self.r_oc_m <= self.r_oo_m:
            raise SettingError(f"r_in_m < r_oc_m <= r_oo_m needed, got {self.r_in_m}, {self.r_oc_m}, {self.r_oo_m}",
                               "r_in_m", "r_oc_m", "r_oo_m")


PRESETS: dict[str, dict] = {
    "no-compression": {"compression": False, "voxel_m": 1.0},
}


def model_settings(config: Config) -> dict:
    """The settings a model file records (`gfjax train`): every field but the decision's."""
    return {k: v for k, v in dataclasses.asdict(config).items() if k not in DECISION_FIELDS}


def survey_halo(config: Config) -> float:
    """The context [m] a survey gives each file (`gfjax.method.Method.survey_halo`), and a
    piece out of core: all that a point's votes read, its patches' centres lying within
    `r_in_m` of it and each patch reading `r_oo_m` around its centre: bcts_1 + bcts_2 cut
    3 x 3 keeps 99.99993 % of the union's labels as a survey, 99.48 % with `r_oo_m` alone
    (`experiments/results/survey_seams.md`)."""
    return float(config.r_oo_m + config.r_in_m)
