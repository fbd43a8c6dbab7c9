"""A short training of the shipped recipe's network (tiny, no refinement, xyz+tophat+smrf) on FILES and a
thinned copy of each, N patches a cloud, 2 epochs, seed 0: prints the losses and a digest of the weights
and statistics. `PYTHONPATH=. python experiments/sparsegf_repro_training.py gfjax/data/samp12-utm.laz 6`
"""
import dataclasses
import hashlib
import sys
import time

import equinox as eqx
import jax
import numpy as np

from gfjax.cli.train import _load
from gfjax.sparsegf import train
from gfjax.sparsegf.config import Config
from gfjax.sparsegf.features import n_features
from gfjax.sparsegf.model import NET_PRESETS, init

t0 = time.time()
files = sys.argv[1].split(",")
patches = int(sys.argv[2]) if len(sys.argv) > 2 else 6
config = Config(features="xyz+tophat+smrf")
clouds = _load(files, None, 2)
data = [train.labelled_cloud(c, config) for c in clouds]
data += train.thinned(clouds, config, copies=1, seed=0)
net_config = dataclasses.replace(NET_PRESETS["tiny"], in_features=n_features(config.features), refine=0)
model = init(net_config, key=jax.random.key(0))
losses = []
model, logs = train.fit(model, data, config=config, epochs=2, batch_size=4, seed=0, lam=0.0,
                        min_patches=patches, max_patches=patches,
                        on_step=lambda epoch, i, n, loss: losses.append(loss[0]))
leaves = [np.asarray(a) for a in jax.tree.leaves(eqx.filter((model.net, model.state), eqx.is_array))]
digest = hashlib.sha256(b"".join(a.tobytes() for a in leaves)).hexdigest()
print("losses", [f"{v:.9g}" for v in losses])
print("weights", digest[:16], len(leaves), "arrays", f"{time.time() - t0:.0f} s")
