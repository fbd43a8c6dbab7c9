"""Training SparseGF (Qin et al. 2026, Sec. 3.3): height-aware loss, Adam, cosine schedule.

One step takes up to 4 voxelized patches (randomly rotated about z, the paper's augmentation,
on a randomly shifted grid of axes) packed into one sparse tensor, runs the network and
minimises the height-aware loss (Eqs. 4-5) over their central points. A cloud trains on the
points the filter's network sees (`filter.seen_points`: noise, withheld points and low outliers
left out of the prior, the features and the patches, and not scored). Labels: ground = class 2,
every other class non-ground; HAG bins from the labelled ground's TIN.
"""
from __future__ import annotations

import dataclasses
import functools
import time
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from gfjax import limits
from gfjax.io.cloud import CloudView, Points
from gfjax.sparsegf import checkpoint
from gfjax.sparsegf.checkpoint import EpochLog
from gfjax.sparsegf.config import Config
from gfjax.sparsegf.features import cloud_features
from gfjax.sparsegf.filter import patches, seen_points
from gfjax.sparsegf.hag import hag_targets
from gfjax.sparsegf.loss import LAMBDA, height_aware_loss
from gfjax.sparsegf.model import Model
from gfjax.sparsegf.pipeline import Pack, group, pack, run_with_room
from gfjax.sparsegf.programs import forward, inputs
from gfjax.sparsegf.vote import decide

# The paper's cosine schedule runs from 1e-1 to 1e-3 (Sec. 3.3). With Adam, group norms and
# batches of 4 patches, 1e-1 made the loss jump from 3.3 to 15.7 at the second step of a tiny
# run here, so the default starts at 1e-2 and ends 100 times lower, as the paper's does.
LR_START = 1e-2
LR_END_RATIO = 1e-2
THIN_LOW_PTS_M2 = 0.1        # sparsest density a thinned training copy is drawn down to [points/m²]
TRAIN_MIN_CAPACITY = 32_768   # voxel rows of the smaller training packs (half a step's time)
CALIBRATION_PASSES = 30       # packs that measure the batch-norm statistics before the first step


class Labelled(NamedTuple):
    """A training cloud: `xyz_m` `(n, 3)` [m], `ground` `(n,)` bool, `hag_bin` `(n,)` int32, and
    `cloud_feats`, its per-cloud inputs (`features.cloud_features`; None until `fit` sets them
    for its feature set, or for a set without any)."""

    xyz_m: np.ndarray
    ground: np.ndarray
    hag_bin: np.ndarray
    cloud_feats: np.ndarray | None = None


def labelled(xyz_m: np.ndarray, classification: np.ndarray, *, ground_class: int = 2) -> Labelled:
    """Every point of `xyz_m` `(n, 3)` [m] labelled by its class `(n,)` (`ground_class`: ground)."""
    cls = np.where(np.asarray(classification) == ground_class, 2, 1)
    t = hag_targets(xyz_m, cls)
    return Labelled(np.asarray(xyz_m, np.float64), t.ground, t.bins)


def labelled_cloud(cloud: CloudView, config: Config, *, ground_class: int = 2) -> Labelled:
    """The points of `cloud` (a `Cloud` or `Points`) that the filter's network sees with
    `config` (`filter.seen_points`), labelled by their class: training's inputs of a cloud
    are the filter's, and the points the filter leaves out are neither inputs nor scored."""
    index = seen_points(cloud, config).index
    return labelled(cloud.xyz_m[index], cloud.classification[index], ground_class=ground_class)


def thinned(clouds: list[CloudView], config: Config, *, copies: int, seed: int, ground_class: int = 2,
            low_pts_m2: float = THIN_LOW_PTS_M2) -> list[Labelled]:
    """`copies` thinned twins of every cloud whose used points are denser than twice
    `low_pts_m2`, each a random subset of its points at a density drawn log-uniformly between
    `low_pts_m2` and the cloud's own, labelled as `labelled_cloud` labels a cloud.

    Density augmentation: a survey may be ten times sparser than any training file, and the
    network's context (how many points a voxel holds, how far the ground lies between them)
    changes with it. Each copy is prepared as the filter would prepare a survey that thin (its
    low outliers, its SMRF prior, its features and height bins from its own points).
    Deterministic given `seed`.
    """
    from gfjax import adaptive

    rng = np.random.default_rng([seed, 1 << 20])
    out = []
    for cloud in clouds:
        density = 1.0 / adaptive.measure(cloud.xyz_m[cloud.filter_mask()]).spacing_m ** 2
        for _ in range(copies if density > 2 * low_pts_m2 else 0):
            target = float(np.exp(rng.uniform(np.log(low_pts_m2), np.log(density))))
            n = cloud.n_points
            keep = np.sort(rng.permutation(n)[:max(1, round(n * target / density))])
            out.append(labelled_cloud(Points.of(cloud, keep), config, ground_class=ground_class))
    return out


class Step(NamedTuple):
    """One training step's inputs: a pack and, per central point row `(P,)` int32, its label
    (1 = ground) and its HAG bin."""

    packed: Pack
    labels: np.ndarray
    bins: np.ndarray


def training_batches(data: list[Labelled], config: Config, *, batch_size: int, rng: np.random.Generator,
                     plans: dict | None = None, min_patches: int = 0, max_patches: int = 0):
    """One epoch of steps: every patch of every cloud once, in random order.

    Augmentation: the grid of patch axes is shifted at random per cloud (the central regions
    fall on new places each epoch) and each patch is rotated about z at random (the paper's).
    A cloud with fewer than `min_patches` patches is drawn again on new shifts and rotations
    until it gives `min_patches`, so a small tile (a forest plot among city blocks) weighs as
    much as the others in an epoch; 0 keeps the paper's one pass. A cloud with more than
    `max_patches` (> 0) gives a random `max_patches` of them, so a square kilometre does not
    outweigh a city block.
    Up to `batch_size` patches are packed per step (`pipeline.pack`, at most
    `pipeline.PACK_VOXELS` voxels unless one patch is larger), into `TRAIN_MIN_CAPACITY` or
    `PACK_VOXELS` rows (a few sparse ISPRS patches fill the first, a dense forest patch needs
    the second); each capacity keeps one pyramid plan across epochs in `plans` (grown only
    when a pack does not fit), so the step compiles once per capacity.
    """
    plans = {} if plans is None else plans
    items = []
    for d in data:
        drawn = []
        while True:
            shift = rng.uniform(0.0, config.step_m, 2)
            draw = lambda: float(rng.uniform(0.0, 2 * np.pi))           # noqa: E731
            more = list(patches(d.xyz_m, config, angle=draw, seed=int(rng.integers(1 << 30)), shift_m=shift,
                                cloud_feats=d.cloud_feats))
            if not more:
                break
            need = min_patches - len(drawn)
            drawn += more if not drawn or need >= len(more) else [more[i] for i in rng.permutation(len(more))[:need]]
            if len(drawn) >= min_patches:
                break
        if 0 < max_patches < len(drawn):
            drawn = [drawn[i] for i in np.sort(rng.permutation(len(drawn))[:max_patches])]
        items += [(d, p) for p in drawn]
    order = [items[i] for i in rng.permutation(len(items))]
    source = {id(p): d for d, p in order}
    for todo in group([p for _, p in order], batch_size):
        packed = pack(todo, batch_size, plans, min_capacity=TRAIN_MIN_CAPACITY)
        labels = packed.per_point([source[id(p)].ground[p.point_index].astype(np.int32) for p in todo])
        bins = packed.per_point([source[id(p)].hag_bin[p.point_index].astype(np.int32) for p in todo])
        yield Step(packed, labels, bins)


def learning_rate(progress: float, lr: float = LR_START) -> float:
    """The cosine schedule at `progress` in [0, 1] of the run: `lr` down to `lr * LR_END_RATIO`."""
    progress = min(max(progress, 0.0), 1.0)
    return lr * (LR_END_RATIO + (1.0 - LR_END_RATIO) * 0.5 * (1.0 + np.cos(np.pi * progress)))


@functools.cache
def optimizer() -> optax.GradientTransformation:
    """Adam whose learning rate is an input of each step (`learning_rate`, set by the host:
    an epoch's step count is only known once its patches are drawn). One object per process:
    the jitted step takes it as a static argument, so a new one would compile the step again."""
    return optax.inject_hyperparams(optax.adam)(learning_rate=LR_START)


@eqx.filter_jit
def _train_step(net, state, opt_state, x, labels, bins, plan, slots, opt, lam):
    def loss_fn(net):
        out, _, overflowed = forward(eqx.nn.inference_mode(net), state, x, plan, slots)
        loss = height_aware_loss(out.cls, out.hag, labels, bins, x.point_valid, lam=lam)
        return loss.total, (loss, overflowed)

    (_, (loss, overflowed)), grads = eqx.filter_value_and_grad(loss_fn, has_aux=True)(net)
    with jax.numpy_dtype_promotion("standard"):          # optax: float ** int32 step count
        updates, opt_state = opt.update(grads, opt_state, eqx.filter(net, eqx.is_array))
    return eqx.apply_updates(net, updates), opt_state, loss, overflowed


def train_step(model: Model, opt_state, step: Step, opt: optax.GradientTransformation, lam: float = LAMBDA,
               lr: float | None = None):
    """One Adam step on a pack, at learning rate `lr` (None: the state's); returns
    `(model, opt_state, loss, overflowed)` (loss: `HeightAwareLoss`; when `overflowed`, the
    pack did not fit its plan and the step is wrong). The batch norms use the model's frozen
    statistics (`calibrate`), as in inference."""
    p = step.packed
    if lr is not None:
        opt_state = opt_state._replace(hyperparams={**opt_state.hyperparams,
                                                     "learning_rate": jnp.asarray(lr, jnp.float32)})
    net, opt_state, loss, overflowed = _train_step(
        model.net, model.state, opt_state, inputs(p), step.labels, step.bins, p.plan, p.slots, opt, lam)
    return Model(net, model.state), opt_state, loss, overflowed


@eqx.filter_jit
def _measure(net, state, x, plan, slots):
    return forward(net, state, x, plan, slots)[1]


def calibrate(model: Model, steps: list[Step], passes: int = CALIBRATION_PASSES) -> Model:
    """The model with its batch norms' statistics measured on up to `passes` packs.

    Each pass normalises with the pack's own statistics and moves the running ones towards
    them (`SparseBatchNorm`'s momentum, 0.1: after 30 packs the initial values weigh 4 %).
    Training then keeps them frozen within an epoch (`fit` measures them again at the start of
    each, as the weights move) and learns the norms' scales and shifts, so the network computes
    the same function in training and in inference. Batch statistics in every step
    would not: a pack holds one dense forest patch or several sparse urban ones, so each
    domain would be normalised by its own statistics in training and by their average in
    inference (measured: a forest tile it was trained on lost 92 % of its ground).
    """
    state = model.state
    for step in steps[:passes]:
        p = step.packed
        state = _measure(model.net, state, inputs(p), p.plan, p.slots)
    return Model(model.net, state)


def init(model: Model):
    """`(optimizer, its state)` for `model`'s network."""
    opt = optimizer()
    with jax.numpy_dtype_promotion("standard"):
        return opt, opt.init(eqx.filter(model.net, eqx.is_array))


def count_patches(data: list[Labelled], config: Config, min_patches: int = 0, max_patches: int = 0) -> int:
    """Patches in an epoch of `training_batches` (about: the count varies with the grid shift)."""
    from gfjax.sparsegf.partition import PartitionConfig, cylinders

    pc = PartitionConfig(step_m=config.step_m, r_oo_m=config.r_oo_m, r_in_m=config.r_in_m)
    counts = [len(cylinders(d.xyz_m, pc)) for d in data]
    capped = [max(c, min_patches) if c else 0 for c in counts]
    return sum(min(c, max_patches) if max_patches > 0 else c for c in capped)


def validation_error(model: Model, data: list[Labelled], config: Config) -> float:
    """Unweighted mean total error (%) of the network alone on labelled clouds (the decision
    `"network"`: what training improves, whatever decision the filter later applies), each
    scored on its points as `labelled_cloud` gives them (those the filter's network sees)."""
    from gfjax.metrics import point_metrics
    from gfjax.sparsegf.filter import ground_probability

    alone = dataclasses.replace(config, decision="network")
    errors = []
    for d in data:
        prob, _, _ = ground_probability(model, d.xyz_m, config, cloud_feats=d.cloud_feats)
        errors.append(100.0 * point_metrics(np.asarray(decide(prob, config=alone)), d.ground)["total_error"])
    return float(np.mean(errors))


def machine() -> dict:
    """What a run's bits depend on besides its code, data and seed, for the model file: the
    CPU (model name and a digest of its flags), the cores this process may use, the instruction
    sets numpy picked its routines by, and the JAX version and `XLA_FLAGS`. Measured: XLA's CPU
    programs round otherwise on one core than on two, and numpy's without AVX-512 otherwise
    than with it, so a run bit-identical to another on one machine need not be on another."""
    import hashlib
    import os

    import jax

    from gfjax.bench.run import cpu_model

    flags = ""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as file:
            flags = next((line.split(":", 1)[1].strip() for line in file if line.startswith(("flags", "Features"))), "")
    except OSError:
        pass
    cpus = limits.processors()
    simd = np.show_config(mode="dicts").get("SIMD Extensions", {})
    return {"processor": cpu_model(), "cpu_flags_sha256": hashlib.sha256(flags.encode()).hexdigest()[:16],
            "cpus": cpus, "numpy": np.__version__, "numpy_simd": list(simd.get("found", [])),
            "jax": jax.__version__, "xla_flags": os.environ.get("XLA_FLAGS", "")}


def fit(model: Model, data: list[Labelled], *, config: Config, epochs: int, batch_size: int, seed: int,
        resume_path=None, validate: list[Labelled] | None = None, lam: float = LAMBDA, lr: float = LR_START,
        min_patches: int = 0, max_patches: int = 0, on_step=None, on_epoch=None):
    """Train `model` for `epochs` epochs; deterministic given `seed` on one machine (`machine`).

    The learning rate follows a cosine from `lr` to `lr * LR_END_RATIO` over the run (per
    step); `min_patches` and `max_patches` are `training_batches`'. Epoch `e` draws its grid shifts, rotations,
    thinning and order from `numpy.random.default_rng([seed, e])`, so a run resumed from the checkpoint at
    `resume_path` (written after every epoch: model, optimizer state, epoch) continues exactly
    as the uninterrupted run would. `on_step(epoch, step, steps in the epoch, [loss, cls,
    hag])` and `on_epoch(EpochLog)` report progress. Returns `(model, [EpochLog])`.
    """
    opt, opt_state = init(model)
    data = [d._replace(cloud_feats=cloud_features(d.xyz_m, config.features)) for d in data]
    validate = [d._replace(cloud_feats=cloud_features(d.xyz_m, config.features)) for d in validate or []]
    first, logs, plans = 0, [], {}
    if resume_path is not None and checkpoint.has_state(resume_path):
        model, opt_state, first, logs = checkpoint.load_state(resume_path, model, opt_state)
    for epoch in range(first, epochs):
        start = time.perf_counter()
        totals = []
        rng = np.random.default_rng([seed, epoch])
        steps = list(training_batches(data, config, batch_size=batch_size, rng=rng, plans=plans,
                                      min_patches=min_patches, max_patches=max_patches))
        model = calibrate(model, steps)
        for i, step in enumerate(steps):
            rate = learning_rate((epoch + i / len(steps)) / epochs, lr)

            def run(packed, model=model, opt_state=opt_state, step=step, rate=rate):
                *out, overflowed = train_step(model, opt_state, step._replace(packed=packed), opt, lam, rate)
                return out, overflowed

            model, opt_state, loss = run_with_room(run, step.packed, plans)
            totals.append([float(loss.total), float(loss.cls), float(loss.hag)])
            if on_step is not None:
                on_step(epoch, i, len(steps), totals[-1])
        mean = np.mean(totals, axis=0) if totals else np.zeros(3)
        val = validation_error(model, validate, config) if validate else None
        logs.append(EpochLog(epoch, *map(float, mean), val, time.perf_counter() - start))
        if resume_path is not None:
            checkpoint.save_state(resume_path, model, opt_state, epoch + 1, logs)
        if on_epoch is not None:
            on_epoch(logs[-1])
    return model, logs
