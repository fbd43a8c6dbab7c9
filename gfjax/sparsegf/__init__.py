"""SparseGF (Qin et al. 2026): the array functions that define what its network sees.

- `partition`: cylinders of radius R_oo = 150 m on a 50 m grid, padded to capacity buckets
  (`cylinders`: the same, each one's points found when asked for, only near a `core`).
- `compress`: convex-mirror context compression, Eqs. 1-3 (pure JAX, vmap over patches).
- `hag_targets`: height above the labelled ground's TIN, quantised into six bins (Sec. 3.3).
- `height_aware_loss`: (1 - lambda) CE_cls + lambda weighted CE_hag, Eqs. 4-5.
- `soft_vote`: mean ground probability over overlapping central regions, Algorithm 1.

```python
part = partition(xyz_m)
for batch in part.batches:
    local = jnp.asarray(batch.local_xyz(xyz_m))                        # (b, cap, 3) float32
    out = jax.vmap(lambda p, v: compress(p, jnp.zeros(2, jnp.float32), valid=v))(local, batch.valid)
```
and the filter itself, with the same shape as every other method:

- `filter(cloud, *, config=None, params=None, returns="all", progress=False, model=None, core=None)`:
  partition -> features -> compress -> voxelize (0.5 m) -> network -> soft vote; `model` is
  a `Model`, a model file, or None for the `tiny` model shipped in gfjax; `core` the points
  whose labels are kept (a survey window's), the rest context only.
- `SparseGFNet`, `NetConfig`, `NET_PRESETS` (`tiny`, `paper`), `Model` (a network and its
  batch-norm statistics), `init`: the network (`model`); `load_model`, `checkpoint`: model
  files; `train`: the training loop (`gfjax train`); `features`: the per-point inputs.
"""
from gfjax.method import Method
from gfjax.sparsegf.compress import CENTRAL_TOL_M, R_IN_M, R_OC_M, R_OO_M, Compressed, compress, compression_ratio
from gfjax.sparsegf.config import PRESETS, RANGES, Config, survey_halo
from gfjax.sparsegf.filter import Diagnostics, filter, load_model, warm
from gfjax.sparsegf.hag import HAG_BIN_EDGES_M, N_HAG_BINS, HagTargets, ground_surface, hag_bins, hag_targets
from gfjax.sparsegf.loss import HAG_WEIGHTS, LAMBDA, HeightAwareLoss, height_aware_loss
from gfjax.sparsegf.model import NET_PRESETS, Model, NetConfig, SparseGFNet, count_parameters, init
from gfjax.sparsegf.partition import STEP_M, Cylinders, Partition, PartitionConfig, PatchBatch, cylinders, partition
from gfjax.sparsegf.vote import UNCOVERED, Vote, decide, soft_vote

Params = None      # no thresholds: the network's weights are SparseGF's parameters
METHOD = Method("sparsegf", filter, Config, Params, PRESETS, RANGES, warm=warm, load_model=load_model,
                takes_terrain=True, takes_core=True, survey_halo=survey_halo)

__all__ = [
    "METHOD", "Config", "Diagnostics", "Model", "NET_PRESETS", "NetConfig", "PRESETS", "Params", "SparseGFNet",
    "count_parameters", "init",
    "filter", "load_model", "warm",
    "CENTRAL_TOL_M", "R_IN_M", "R_OC_M", "R_OO_M", "STEP_M", "HAG_BIN_EDGES_M", "N_HAG_BINS",
    "HAG_WEIGHTS", "LAMBDA", "UNCOVERED",
    "Compressed", "Cylinders", "HagTargets", "HeightAwareLoss", "Partition", "PartitionConfig", "PatchBatch", "Vote",
    "compress", "compression_ratio", "ground_surface", "hag_bins", "hag_targets",
    "height_aware_loss", "cylinders", "partition", "decide", "soft_vote",
]
