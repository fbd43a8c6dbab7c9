"""SparseGF as a ground filter: partition, compress, network, soft vote (Qin et al. 2026, Fig. 1)."""
from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import functools
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from gfjax import adaptive, cache, spikes
from gfjax.errors import InputError
from gfjax.io.cloud import CloudView, Frame
from gfjax.result import Result
from gfjax.sparsegf import checkpoint
from gfjax.sparsegf.config import CORE_REACH_M, DECISION_FIELDS, DENSITY_SLACK, LEVEL_TOLERANCE_M, Config
from gfjax.sparsegf.features import cloud_features, n_features
from gfjax.sparsegf.model import Model
from gfjax.sparsegf.partition import PartitionConfig, cylinders
from gfjax.sparsegf.pipeline import (
    PACK_SLOTS,
    WARM_KEPT,
    WARM_MEMBERS,
    fits_tiny_pack,
    group,
    min_capacity,
    pack,
    prepare,
    run_with_room,
    tiny_pack,
    unpack,
)
from gfjax.sparsegf.programs import predict, prepare_point_inputs, prepare_predict, vote
from gfjax.sparsegf.smrf_prior import smrf_heights
from gfjax.sparsegf.vote import decide
from gfjax.tiling.buckets import power_bucket


class Diagnostics(NamedTuple):
    """`prob_ground` `(n,)` mean ground probability of the votes (0 for unused points),
    `votes` `(n,)` int32 number of patches that classified each point, `n_patches`,
    `smrf_ground` `(n,)` bool SMRF's verdict (None when neither the inputs nor the decision
    read SMRF)."""

    prob_ground: np.ndarray
    votes: np.ndarray
    n_patches: int
    smrf_ground: np.ndarray | None = None


def patches(xyz_m: np.ndarray, config: Config, *, angle: float | Callable[[], float] = 0.0, seed: int = 0,
            shift_m=(0.0, 0.0), cloud_feats: np.ndarray | None = None, count: Callable[[int], None] | None = None,
            frame: Frame | None = None, core: np.ndarray | None = None):
    """Every voxelized patch of a cloud, in the order of their cells (`angle`: a rotation about
    z [rad] for every patch, or a function drawing one per patch; `cloud_feats`: the cloud's
    `features.cloud_features`, computed here when None and the feature set has some; `count`
    is told the number of patches once the partition is made, before the first is yielded).
    Each patch's points are found as it is made (`partition.cylinders`).

    `frame` (filtering; `grid_frame`): the patch grid is laid on its box, and each patch's
    context is thinned with the seed of its cell there (`Cylinders.cells`), so a patch whose
    cylinder a window holds whole is the same patch in every window of that frame. Without
    it (training), on the points' own box, thinned with the seed of its row. `core` bool
    `(n,)`: only the patches that vote on points within `CORE_REACH_M` of these
    (`partition.cylinders`)."""
    if cloud_feats is None:
        cloud_feats = cloud_features(xyz_m, config.features)
    found = cylinders(xyz_m, PartitionConfig(step_m=config.step_m, r_oo_m=config.r_oo_m, r_in_m=config.r_in_m),
                      shift_m=shift_m, box=None if frame is None else (frame.origin_m[:2], frame.upper_m),
                      core=core, core_reach_m=CORE_REACH_M)
    if count is not None:
        count(len(found))
    for p in range(len(found)):
        name = p if frame is None else int(found.cells[p])
        yield prepare(xyz_m, found.members(p), found.centers_m[p], name, config=config,
                      angle=angle() if callable(angle) else angle, seed=seed, cloud_feats=cloud_feats)


# Packs the network runs at once. One pack's program keeps about 1.6 of 2 cores busy (its
# gathers and scatters run on one thread), so a second beside it fills the gaps: on bcts_2,
# 0.48 s a pack instead of 0.61 (2 cores); memory grows by one pack's working set.
IN_FLIGHT = 2


def ground_probability(model: Model, xyz_m: np.ndarray, config: Config, *, progress: bool = False,
                       cloud_feats: np.ndarray | None = None, frame: Frame | None = None,
                       core: np.ndarray | None = None):
    """Soft-voted ground probability and vote count per point of `xyz_m` `(n, 3)` [m]
    (`cloud_feats`, `frame`, `core`: as `patches`; with `core`, the points far from it have
    no vote).

    Patches are prepared on the host while `IN_FLIGHT` packs run, each on a worker thread (a
    pack whose pyramid overflowed its plan runs again with a grown plan there). Packs are read
    back in the order they were made, so the votes, and the labels, do not depend on timing.
    """
    n = len(xyz_m)
    index, prob = [], []
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(desc="sparsegf patches", unit="patch", leave=False)
    plans: dict = {}

    def run(packed):
        return np.asarray(run_with_room(lambda q: predict(model, q), packed, plans))

    def finish(packed, future):
        for patch, values in zip(packed.patches, unpack(packed, future.result())):
            index.append(patch.point_index)
            prob.append(values)
        if bar is not None:
            bar.update(len(packed.patches))

    running: collections.deque = collections.deque()
    n_patches = [0]
    with concurrent.futures.ThreadPoolExecutor(IN_FLIGHT, thread_name_prefix="sparsegf-pack") as pool:
        def total(count: int) -> None:
            n_patches[0] = count
            if bar is not None:
                bar.reset(total=count)

        for todo in group(patches(xyz_m, config, cloud_feats=cloud_feats, count=total, frame=frame, core=core),
                          PACK_SLOTS):
            packed = pack(todo, PACK_SLOTS, plans,
                          min_capacity=min_capacity(todo, cloud_voxels_at_most=n_patches[0] * n))
            running.append((packed, pool.submit(run, packed)))
            if len(running) > IN_FLIGHT:
                finish(*running.popleft())
        while running:
            finish(*running.popleft())
    if bar is not None:
        bar.close()
    if not index:
        return np.zeros(n, np.float32), np.zeros(n, np.int32), 0
    # votes and points padded to powers of two: the vote compiles a few times per machine,
    # not once per cloud
    votes = np.concatenate(index)
    size = power_bucket(len(votes), minimum=1024)
    merged = vote(np.concatenate([votes, np.full(size - len(votes), -1)]),
                  np.concatenate([*prob, np.zeros(size - len(votes), np.float32)]), power_bucket(n, minimum=1024))
    return np.asarray(merged.prob_ground)[:n], np.asarray(merged.count)[:n], len(index)


# The generated scenes `warm` filters, flat squares (side [m], points): one a full pack, one
# a small pack, one a tiny pack (`pipeline.min_capacity`).
WARM_SCENES = ((120.0, 30_000), (20.0, 1_500), (20.0, 400))


@cache.persistent
def warm(config: Config | None = None, params=None, *, progress: bool = False) -> int:
    """Load or compile ahead the programs a cloud's patches run (`gfjax warmup`; the command
    line keeps them): the shipped network on packs of `pipeline.PACK_VOXELS` and
    `pipeline.SMALL_PACK_VOXELS` and `pipeline.TINY_PACK_VOXELS` voxels with their standard
    plans, the costly ones, by filtering three small generated scenes; then the per-patch feature program at every padded patch size of
    `pipeline.WARM_MEMBERS` x `pipeline.WARM_KEPT`, into the program store (none when it is
    off). The vote program of another cloud size still compiles on first use
    (0.1 s; then kept), and so do SMRF's programs for a model that reads SMRF's surface, unless
    `gfjax.smrf.warm` prepared them (`gfjax warmup` does both). Returns the number of
    programs prepared: 3 networks and the feature programs."""
    from gfjax import aot
    from gfjax.io.cloud import Cloud

    rng = np.random.default_rng(0)
    model, trained_with = load_model()
    config = trained_with if config is None else config
    for side_m, n in WARM_SCENES:
        xy = rng.uniform(0.0, side_m, (n, 2))
        z = 100.0 + 0.02 * xy[:, 0] + rng.normal(0.0, 0.05, n)
        filter(Cloud.from_xyz(np.column_stack([xy + [5e5, 5e6], z])), config=config, params=params,
               progress=progress, model=model)
    if aot.enabled_folder() is None:                   # the store is off: nothing would be kept
        return len(WARM_SCENES)
    sizes = [(m, k) for m in WARM_MEMBERS for k in WARM_KEPT if k <= m]
    if progress:
        from tqdm.auto import tqdm
        sizes = tqdm(sizes, desc="sparsegf patch sizes", unit="program")
    for members, kept in sizes:
        prepare_point_inputs(config, members, kept)
    return len(WARM_SCENES) + len(sizes)


def load_model(path=None) -> tuple[Model, Config]:
    """The model at `path` (None: the model shipped in gfjax) and the settings it was trained
    with; the decision (`config.DECISION_FIELDS`) keeps `Config`'s defaults. Read once per
    process while the file stays as it is (its size and time are part of the key)."""
    path = Path(path) if path is not None else checkpoint.shipped_path()
    try:
        stamp = path.stat()
        key = (str(path.resolve()), stamp.st_size, stamp.st_mtime_ns)
    except OSError:
        key = None                              # `checkpoint.load` says what is wrong with it
    return _load_model(path, key) if key is not None else _read_model(path)


@functools.lru_cache(maxsize=4)
def _load_model(path: Path, key: tuple) -> tuple[Model, Config]:
    del key
    return _read_model(path)


def _read_model(path: Path) -> tuple[Model, Config]:
    model, header = checkpoint.load(path)
    stored = header.get("meta", {}).get("config", {})
    names = {f.name for f in dataclasses.fields(Config)} - set(DECISION_FIELDS)
    try:
        config = Config(**{k: v for k, v in stored.items() if k in names})
    except (TypeError, ValueError) as err:
        raise InputError(f"{path}: model settings are unusable ({err})") from None
    have = model.net.config.in_features
    if n_features(config.features) != have:
        raise InputError(f"{path}: the network takes {have} input features, "
                         f"its settings give {n_features(config.features)} ({config.features})")
    return model, config


def trained_density(path=None) -> tuple[float, float] | None:
    """The points per m² the model at `path` (None: the shipped one) was trained on, lowest and
    highest of its files (`gfjax train` records them); None for a model file without them."""
    found = checkpoint.read_header(path or checkpoint.shipped_path()).get("meta", {}).get("inputs", {})
    density = found.get("density_pts_m2") if isinstance(found, dict) else None
    if (isinstance(density, list) and len(density) == 2 and all(isinstance(v, (int, float)) for v in density)
            and 0 < density[0] <= density[1]):
        return float(density[0]), float(density[1])
    return None


def level_ground_kept(xyz_m: np.ndarray, ground: np.ndarray, smrf_ground: np.ndarray, *,
                       k: int = spikes.NEIGHBOURS) -> np.ndarray:
    """`ground` with SMRF's ground points that the network rejected given back where they lie
    level with the ground it kept: within `LEVEL_TOLERANCE_M` of the median height of their `k`
    nearest kept ground points (x, y). The network may take understory and low objects off
    SMRF's ground, not ground that is level with ground: off the surveys it learned from it
    rejects such points confidently (half of a flat plane of 20 points/m²).

    Args:
      xyz_m: float `(n, 3)` [m]; ground, smrf_ground: bool `(n,)`.

    Returns:
      bool `(n,)`.
    """
    from scipy.spatial import cKDTree

    rejected = np.flatnonzero(smrf_ground & ~ground)
    kept = np.flatnonzero(ground)
    if rejected.size == 0 or kept.size < k:
        return ground
    xyz = np.asarray(xyz_m, dtype=np.float64)
    origin = xyz[kept, :2].min(axis=0)
    _, neighbour = cKDTree(xyz[kept, :2] - origin).query(xyz[rejected, :2] - origin, k=k)
    level = np.abs(xyz[rejected, 2] - np.median(xyz[kept[neighbour], 2], axis=1)) <= LEVEL_TOLERANCE_M
    out = ground.copy()
    out[rejected[level]] = True
    return out


class Seen(NamedTuple):
    """The points of a cloud SparseGF's network sees: `cloud`, the cloud with its low outliers
    hidden where they are (`adaptive.Hidden`), `index` int64 `(k,)` the rows of the points the
    prior, the features and the patches are made of, and `terrain`, the used points'
    `adaptive.Terrain` (or the one given: a survey's; None without a used point)."""

    cloud: CloudView
    index: np.ndarray
    terrain: adaptive.Terrain | None


def seen_points(cloud: CloudView, config: Config, *, returns: str = "all",
                terrain: adaptive.Terrain | None = None) -> Seen:
    """The points the network sees of `cloud` (`Seen`), for the filter and for training alike:
    the used returns (`cloud.filter_mask(returns)`: noise and withheld points left out), and
    under the default decision less the cloud's low outliers (`adaptive.hide`, on `terrain`
    when given, else the used points'), as SMRF hides them (`gfjax.smrf.config.HIDES_LOW_OUTLIERS`):
    the prior and the patches are made without them, the filter calls them non-ground and
    training does not score them."""
    index = np.flatnonzero(cloud.filter_mask(returns))
    if not len(index):
        terrain = None
    elif terrain is None:
        terrain = adaptive.measure(cloud.xyz_m[index], cloud.xyz_m[cloud.filter_mask("last")])
    if config.decision == "network+smrf" and terrain is not None:
        hidden = adaptive.hide(cloud, terrain, returns=returns)
        if hidden is not None:
            cloud = adaptive.Hidden(cloud, hidden)
            index = np.flatnonzero(cloud.filter_mask(returns))
    return Seen(cloud, index, terrain)


def grid_frame(cloud: CloudView, returns: str = "all") -> Frame | None:
    """The frame the patch grid of `cloud` is laid on (`patches`): its own (`cloud.frame`: a
    survey's, on its windows) or the box of its used points, the same box a survey of the one
    file would have (None without a used point)."""
    if cloud.frame is not None:
        return cloud.frame
    used = cloud.filter_mask(returns)
    if not used.any():
        return None
    return Frame.of(cloud.xyz_m if used.all() else cloud.xyz_m[used])


@cache.persistent
def filter(cloud: CloudView, *, config: Config | None = None, params=None, returns: str = "all",
           progress: bool = False, model: Model | str | None = None,
           terrain: adaptive.Terrain | None = None, core: np.ndarray | None = None) -> Result:
    """Classify ground points with SparseGF.

    Args:
      cloud: the point cloud (`cloud.xyz_m`, metres; only `cloud.filter_mask(returns)` used).
      config: static settings (default: those the model was trained with; `Config()` for a
        model passed as an object: the paper's radii, 0.5 m voxels).
      params: unused (SparseGF's parameters are the network's weights); must be None.
      returns: "all" or "last".
      progress: show a bar over patches.
      model: a `Model` (`gfjax.sparsegf.init`, `train.fit`), a model file path, or None for
        the model shipped in gfjax.
      terrain: the terrain (`gfjax.adaptive.Terrain`) its low-outlier test, density check and
        ground-spike guard read in place of the cloud's own: a survey's, so that each window
        is judged as the whole survey is (`gfjax.method.Method.takes_terrain`).
      core: bool `(n,)`, the points whose labels the caller keeps (a survey window's core,
        `gfjax.method.Method.takes_core`), or None for all. Only the patches that vote on
        points within `config.CORE_REACH_M` of them run; a point no patch votes on takes
        SMRF's verdict under the default decision, and is no ground under the paper's.

    Returns:
      `Result(ground, Diagnostics)`; ground by `config.decision` (`vote.decide`): by default
      the cloud's low outliers hidden first (`gfjax.adaptive.hide`: non-ground, in no patch and
      not in SMRF's prior), then SMRF's verdict (run once over the cloud) unless the network's mean vote is confident
      against it and it stands off the ground kept around it (`level_ground_kept`), then
      ground over lower returns and ground spikes dropped (`gfjax.spikes.guard`); `decision="network"` is the
      paper's mean vote > `ground_probability`, as it is.
    """
    seen = None                              # the densities a model file says it was trained on
    if not isinstance(model, Model):
        seen = trained_density(model)
        model, trained_with = load_model(model)
        config = trained_with if config is None else config
    config = Config() if config is None else config
    if n_features(config.features) != model.net.config.in_features:
        raise InputError(f"sparsegf: the model takes {model.net.config.in_features} input features, the settings' "
                         f"feature set {config.features!r} gives {n_features(config.features)}")
    if params is not None:
        raise InputError("sparsegf: takes no params (its parameters are the model's weights; see --model)")
    try:
        cloud.filter_mask(returns)
    except ValueError as err:
        raise InputError(f"{cloud.name}: --returns: {err}") from None
    if core is not None:
        core = np.asarray(core, bool)
        if core.shape != (cloud.n_points,):
            raise InputError(f"sparsegf: core must have shape ({cloud.n_points},), got {core.shape}")
    frame = grid_frame(cloud, returns)
    cloud, used_index, terrain = seen_points(cloud, config, returns=returns, terrain=terrain)
    xyz_m = cloud.xyz_m[used_index]
    if seen is not None and terrain is not None and config.decision == "network+smrf":
        density, (low, high) = 1.0 / terrain.spacing_m ** 2, seen
        if not low / DENSITY_SLACK <= density <= high * DENSITY_SLACK:
            from gfjax import smrf as smrf_method

            note = (f"sparsegf: {density:.3g} points/m², beyond the {low:.3g}-{high:.3g} its model was trained on "
                    f"(a factor {DENSITY_SLACK:g} either side): SMRF's labels kept")
            return smrf_method.filter(cloud, returns=returns)._replace(notes=(note,))
    if fits_tiny_pack(xyz_m, config):
        # the network's program loaded first, in this thread: SMRF's programs then reuse the
        # scratch memory of its load (a 30-point file's process: 390 MB at most, not 415)
        prepare_predict(model, tiny_pack(model.net.config.in_features))
    smrf = smrf_heights(xyz_m, cloud.frame) if config.reads_smrf else None
    smrf_ground = None if smrf is None else smrf[:, 1] >= 0
    if core is not None:
        core = core[used_index]
    prob, votes, n_patches = ground_probability(model, xyz_m, config, progress=progress,
                                                cloud_feats=cloud_features(xyz_m, config.features, smrf=smrf), frame=frame,
                                                core=core)

    def full(values, dtype):                     # per used point -> per point of the cloud (0 elsewhere)
        out = np.zeros(cloud.n_points, dtype)
        out[used_index] = values
        return out

    decided = np.asarray(decide(prob, smrf_ground, config=config))
    if config.decision == "network+smrf" and core is not None:     # the points far from the core: no patch ran
        decided = np.where(votes > 0, decided, smrf_ground)
    ground = full(decided, bool)
    if config.decision == "network+smrf" and terrain is not None:   # the paper's bare decision stays bare
        ground = spikes.guard(cloud.xyz_m, cloud.filter_mask("all"),
                              level_ground_kept(cloud.xyz_m, ground, full(smrf_ground, bool)),
                              spacing_m=terrain.spacing_m, slope_p90=terrain.slope_p90)
    diagnostics = Diagnostics(full(prob, np.float32), full(votes, np.int32), n_patches,
                              None if smrf_ground is None else full(smrf_ground, bool))
    return Result(ground=ground, diagnostics=diagnostics)
