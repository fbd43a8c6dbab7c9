"""SparseGF as a ground filter: partition, compress, network, soft vote (Qin et al. 2026, Fig. 1)."""
from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import numpy as np

from gfjax.errors import InputError
from gfjax.io.cloud import Cloud
from gfjax.result import Result
from gfjax.sparsegf import checkpoint
from gfjax.sparsegf.config import Config
from gfjax.sparsegf.model import SparseGFNet
from gfjax.sparsegf.partition import PartitionConfig, partition
from gfjax.sparsegf.pipeline import make_patch, predict_batch, run_with_room, stack
from gfjax.sparsegf.vote import soft_vote


class Diagnostics(NamedTuple):
    """`prob_ground` `(n,)` mean ground probability of the votes (0 for unused points),
    `votes` `(n,)` int32 number of patches that classified each point, `n_patches`."""

    prob_ground: np.ndarray
    votes: np.ndarray
    n_patches: int


def patches(xyz_m: np.ndarray, config: Config, *, angle: float = 0.0, seed: int = 0):
    """Every voxelized patch of a cloud, in partition order."""
    part = partition(xyz_m, PartitionConfig(step_m=config.step_m, r_oo_m=config.r_oo_m, r_in_m=config.r_in_m))
    for batch in part.batches:
        for row, pid in enumerate(batch.patch_id):
            members = batch.index[row][batch.valid[row]]
            yield make_patch(xyz_m, members, part.centers_m[pid], int(pid), config=config, angle=angle, seed=seed)


def ground_probability(net: SparseGFNet, xyz_m: np.ndarray, config: Config, *, progress: bool = False):
    """Soft-voted ground probability and vote count per point of `xyz_m` `(n, 3)` [m]."""
    n = len(xyz_m)
    index, prob, central = [], [], []
    todo = list(patches(xyz_m, config))
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(todo), desc="sparsegf patches", unit="patch", leave=False)
    plans = {}

    def run(batch):
        b = batch.patch
        return predict_batch(net, b.coords, b.feats, b.vvalid, b.point_voxel, b.central, batch.plan)

    for start in range(0, len(todo), config.batch_size):
        group = todo[start:start + config.batch_size]
        batch = stack(group, plans)
        b = batch.patch
        p = np.asarray(jax.device_get(run_with_room(run, batch, plans)))
        for i in range(len(group)):
            index.append(b.index[i]), prob.append(p[i]), central.append(b.central[i])
        if bar is not None:
            bar.update(len(group))
    if bar is not None:
        bar.close()
    if not index:
        return np.zeros(n, np.float32), np.zeros(n, np.int32), 0
    vote = soft_vote(np.concatenate(index), np.concatenate(prob), n, mask=np.concatenate(central))
    return np.asarray(vote.prob_ground), np.asarray(vote.count), len(todo)


def load_model(path=None) -> tuple[SparseGFNet, Config]:
    """The network at `path` (None: the model shipped in gfjax) and the settings it was trained with."""
    net, header = checkpoint.load(path)
    stored = header.get("meta", {}).get("config", {})
    names = {f.name for f in dataclasses.fields(Config)}
    try:
        config = Config(**{k: v for k, v in stored.items() if k in names})
    except (TypeError, ValueError) as err:
        raise InputError(f"{path or checkpoint.SHIPPED}: model settings are unusable ({err})") from None
    return net, config


def filter(cloud: Cloud, *, config: Config | None = None, params=None, returns: str = "all",
           progress: bool = False, model: SparseGFNet | str | None = None) -> Result:
    """Classify ground points with SparseGF.

    Args:
      cloud: the point cloud (`cloud.xyz_m`, metres; only `cloud.filter_mask(returns)` used).
      config: static settings (default: those the model was trained with; `Config()` for a
        network passed as an object: the paper's radii, 0.5 m voxels).
      params: unused (SparseGF's parameters are the network's weights); must be None.
      returns: "all" or "last".
      progress: show a bar over patches.
      model: a `SparseGFNet`, a model file path, or None for the model shipped in gfjax.

    Returns:
      `Result(ground, Diagnostics)`; ground = mean vote > `config.ground_probability`.
    """
    if isinstance(model, SparseGFNet):
        net = model
    else:
        net, trained_with = load_model(model)
        config = trained_with if config is None else config
    config = Config() if config is None else config
    if params is not None:
        raise InputError("sparsegf: takes no params (its parameters are the model's weights; see --model)")
    try:
        used = cloud.filter_mask(returns)
    except ValueError as err:
        raise InputError(f"{cloud.name}: --returns: {err}") from None
    used_index = np.flatnonzero(used)
    prob, votes, n_patches = ground_probability(net, cloud.xyz_m[used_index], config, progress=progress)
    ground = np.zeros(cloud.n_points, bool)
    ground[used_index] = prob > config.ground_probability
    full_prob = np.zeros(cloud.n_points, np.float32)
    full_prob[used_index] = prob
    full_votes = np.zeros(cloud.n_points, np.int32)
    full_votes[used_index] = votes
    return Result(ground=ground, diagnostics=Diagnostics(full_prob, full_votes, n_patches))
