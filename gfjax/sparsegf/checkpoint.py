"""Model files: a one-line JSON header, then the weights as `eqx.tree_serialise_leaves` bytes.

The header names the format, the gfjax version that wrote it, the network's `NetConfig`
and what the trainer recorded (data, seed, epochs); the body holds the network and its state
(the batch norms' running statistics). `load` checks each before reading a
weight, so a missing, truncated or foreign file fails with one line naming the file.
"""
from __future__ import annotations

import dataclasses
import io
import json
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple

import equinox as eqx
import jax
import numpy as np

from gfjax.errors import InputError
from gfjax.io import atomic
from gfjax.sparsegf.model import Model, NetConfig, init

MAGIC = "gfjax-sparsegf-model"
FORMAT = 3                         # 3: the point branch; 2: batch norms and their statistics, input features in the settings
SHIPPED = "sparsegf_tiny.eqx"      # the model inside the package (gfjax/data)


def save(path: str | Path, model: Model, meta: dict[str, Any] | None = None) -> None:
    """Write `model` to `path` atomically (a temporary file renamed into place)."""
    from gfjax import __version__

    header = {"magic": MAGIC, "format": FORMAT, "gfjax": __version__,
              "net": dataclasses.asdict(model.net.config), "meta": meta or {}}
    _write(path, header, tuple(model))


def _write(path: str | Path, header: dict[str, Any], tree) -> None:
    """A JSON header line then `tree`'s leaves, written atomically (`gfjax.io.atomic`: a full
    disk is an `InputError` naming the file, and leaves nothing behind)."""
    buffer = io.BytesIO()
    eqx.tree_serialise_leaves(buffer, tree)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic.atomic_output(path, force=True) as tmp:
        with open(tmp, "wb") as f:
            f.write(json.dumps(header).encode() + b"\n")
            f.write(buffer.getvalue())


def read_header(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        found = path.is_file()  # a FIFO or device is not: never opened
    except OSError as err:  # a name too long, a loop of links
        raise InputError(f"{path}: cannot open ({err.strerror or err})") from None
    if not found:
        raise InputError(f"{path}: model file not found")
    try:
        with open(path, "rb") as f:
            line = f.readline(1 << 16)
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from None
    try:
        header = json.loads(line)
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
        raise InputError(f"{path}: not a gfjax SparseGF model (no header)") from None
    if not isinstance(header, dict) or header.get("magic") != MAGIC:
        raise InputError(f"{path}: not a gfjax SparseGF model (no header)")
    if header.get("format") != FORMAT:
        raise InputError(f"{path}: model format {header.get('format')} is not {FORMAT}; "
                         f"written by gfjax {header.get('gfjax')}, retrain or use that version")
    return header


def shipped_path() -> Path:
    """The model file inside the package."""
    return Path(str(resources.files("gfjax") / "data" / SHIPPED))


def load(path: str | Path | None = None) -> tuple[Model, dict[str, Any]]:
    """The model stored at `path` (default: the model shipped in the package) and its header."""
    if path is None:
        path = shipped_path()
    path = Path(path)
    header = read_header(path)
    try:
        config = NetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in header["net"].items()})
    except (TypeError, ValueError, KeyError) as err:
        raise InputError(f"{path}: model header has an unusable network description ({err})") from None
    # shapes only: initialising the weights just to overwrite them costs a second of small
    # programs, and tracing their random draws 0.13 s
    like = eqx.filter_eval_shape(lambda: tuple(init(config, key=None)))
    like = jax.tree.map(lambda a: np.empty(a.shape, a.dtype) if isinstance(a, jax.ShapeDtypeStruct) else a, like)
    with open(path, "rb") as f:
        f.readline(1 << 16)
        try:
            host = eqx.tree_deserialise_leaves(f, like, filter_spec=_host_leaf)
        except Exception as err:       # truncated or mismatched weights: report, never a traceback
            raise InputError(f"{path}: model weights are truncated or do not match the header "
                             f"({type(err).__name__})") from None
        if f.read(1):
            raise InputError(f"{path}: model file has trailing bytes after the weights")
    arrays = [a for a in jax.tree.leaves(host) if isinstance(a, np.ndarray) and np.issubdtype(a.dtype, np.inexact)]
    bad = sum(int(np.count_nonzero(~np.isfinite(a))) for a in arrays)
    if bad:
        # a diverged training writes such weights; its votes would be NaN, and every point no ground
        raise InputError(f"{path}: model weights hold {bad:,} values that are not finite (NaN or inf): "
                         "a training that diverged?")
    # one transfer for every leaf: `jnp.load` per leaf (equinox's default) runs a small
    # program for each leaf shape, 40 of them, 0.3 s of a 30-point file's process
    leaves, treedef = jax.tree.flatten(host)
    arrays_at = [i for i, a in enumerate(leaves) if isinstance(a, np.ndarray)]
    for i, a in zip(arrays_at, jax.device_put([leaves[i] for i in arrays_at])):
        leaves[i] = a
    return Model(*jax.tree.unflatten(treedef, leaves)), header


def _host_leaf(f, like):
    """A weight as a numpy array (`eqx.tree_deserialise_leaves`' `filter_spec`): the bytes
    `jnp.save` wrote, checked against the shape and dtype the header's network gives."""
    if isinstance(like, np.ndarray):
        a = np.load(f, allow_pickle=False)
        if a.shape != tuple(like.shape) or a.dtype != like.dtype:
            raise ValueError(f"a weight of shape {a.shape} {a.dtype}, the network needs {like.shape} {like.dtype}")
        return a
    return eqx.default_deserialise_filter_spec(f, like)


def has_state(path: str | Path) -> bool:
    return Path(path).is_file()


def state_epoch(path: str | Path) -> int:
    """Epochs done by the training state at `path` (0 when there is none or it is unreadable)."""
    try:
        with open(path, "rb") as f:
            return int(json.loads(f.readline(1 << 20)).get("epoch", 0))
    except (OSError, ValueError, AttributeError, TypeError, RecursionError):
        return 0


class EpochLog(NamedTuple):
    """What one epoch did: mean losses over its steps, the validation total error (None without
    validation files), its wall time [s]."""

    epoch: int
    loss: float
    loss_cls: float
    loss_hag: float
    val_total_error: float | None
    seconds: float


def save_state(path: str | Path, model: Model, opt_state, epoch: int, logs: list) -> None:
    """The training state after `epoch` epochs (model, optimizer state, epoch logs), atomically."""
    header = {"magic": MAGIC + "-state", "format": FORMAT, "epoch": epoch,
              "net": dataclasses.asdict(model.net.config), "logs": [log._asdict() for log in logs]}
    _write(path, header, (tuple(model), opt_state))


def load_state(path: str | Path, model: Model, opt_state):
    """`(model, opt_state, epochs done, logs)` from `save_state`; `model` and `opt_state` give
    the shapes."""
    path = Path(path)
    with open(path, "rb") as f:
        try:
            header = json.loads(f.readline(1 << 20))
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
            raise InputError(f"{path}: not a gfjax SparseGF training state") from None
        if not isinstance(header, dict) or header.get("magic") != MAGIC + "-state":
            raise InputError(f"{path}: not a gfjax SparseGF training state")
        if header.get("net") != json.loads(json.dumps(dataclasses.asdict(model.net.config))):
            raise InputError(f"{path}: training state of another network preset; remove it or use its preset")
        try:
            parts, opt_state = eqx.tree_deserialise_leaves(f, (tuple(model), opt_state))
        except Exception as err:
            raise InputError(f"{path}: training state is truncated ({type(err).__name__})") from None
    return Model(*parts), opt_state, int(header["epoch"]), [EpochLog(**log) for log in header["logs"]]
