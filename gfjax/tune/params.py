"""Bounded parametrisation of the tuned thresholds, and the `params.json` file.

Optax works on unconstrained reals `raw`; a parameter with bounds `[lo, hi]` is
`lo + (hi - lo) * sigmoid(raw)` (SPEC section 7), so no step can leave its bounds. The prior
toward the defaults is measured on the bounded scale, `((value - default) / (hi - lo))^2`.

`write_params` writes the `params.json` whose layout `gfjax.io.params_file` documents and
reads (so `gfjax filter --params` applies it).
"""
from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from gfjax.io.atomic import atomic_output
from gfjax.io.params_file import read_params
from gfjax.params import declared_defaults

__all__ = ["Bound", "bound", "to_raw", "from_raw", "prior_penalty", "write_params", "read_params"]


class Bound(NamedTuple):
    """One tuned scalar: its name (a `Params` field), default, bounds and unit (`bound` reads
    the default from the method's `Params`: one place)."""

    name: str
    default: float
    lo: float
    hi: float
    unit: str


def bound(params_type: type, name: str, lo: float, hi: float, unit: str) -> Bound:
    """The `Bound` of `params_type`'s field `name`, its default the field's declared one."""
    return Bound(name, float(declared_defaults(params_type)[name]), lo, hi, unit)


def _check(bounds: Sequence[Bound]) -> None:
    for b in bounds:
        if not (b.lo < b.default < b.hi):
            raise ValueError(f"{b.name}: default {b.default} must lie strictly inside ({b.lo}, {b.hi})")


def to_raw(values: Mapping[str, float | np.floating], bounds: Sequence[Bound]) -> Float[Array, " p"]:
    """Unconstrained `raw` (float32 `(p,)`) of `values` (clipped just inside the bounds)."""
    _check(bounds)
    out = []
    for b in bounds:
        frac = (float(values[b.name]) - b.lo) / (b.hi - b.lo)
        frac = min(max(frac, 1e-4), 1 - 1e-4)
        out.append(math.log(frac / (1 - frac)))
    return jnp.asarray(out, jnp.float32)


def from_raw(raw: Float[ArrayLike, "... p"], bounds: Sequence[Bound]) -> Float[Array, "... p"]:
    """Bounded values `lo + (hi - lo) * sigmoid(raw)`, same shape as `raw` (jit/vmap-able)."""
    lo, span = _row([b.lo for b in bounds], raw), _row([b.hi - b.lo for b in bounds], raw)
    return lo + span * jax.nn.sigmoid(raw)


def _row(values: list[float], like: ArrayLike) -> Array:
    """`values` as an array broadcastable against `like` `(..., p)` (explicit rank)."""
    return jnp.asarray(values, like.dtype).reshape((1,) * (like.ndim - 1) + (len(values),))


def prior_penalty(raw: Float[ArrayLike, "... p"], bounds: Sequence[Bound],
                  center: Float[ArrayLike, " p"] | None = None) -> Float[Array, ...]:
    """`sum_k ((value_k - center_k) / (hi_k - lo_k))^2`: distance to `center` (default: the
    bounds' defaults; a fit that starts from values the cloud chose passes those) on the
    bounded scale (0 there), summed over the last axis."""
    values = from_raw(raw, bounds)
    span = _row([b.hi - b.lo for b in bounds], raw)
    default = _row([b.default for b in bounds], raw) if center is None else \
        jnp.asarray(center, raw.dtype).reshape((1,) * (raw.ndim - 1) + (len(bounds),))
    return jnp.sum(jnp.square((values - default) / span), axis=-1)


def write_params(path: str | os.PathLike, *, method: str, values: Mapping[str, float | np.floating],
                 units: Mapping[str, str], extra: Mapping[str, Any] | None = None) -> Path:
    """Write a params.json atomically (temporary file + rename). Returns the path.

    Args:
      method: the method name (`gfjax.methods.PACKAGES` key).
      values: `{key: float}` for `make_config_and_params` (Config or Params fields).
      units: `{key: unit}` for each value.
      extra: more report entries (fitted keys, validation figures); must not hold
        `method`, `gfjax_version`, `units` or `values`.
    """
    from gfjax import __version__

    clean = {}
    for key, value in values.items():
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f"value of {key!r} must be finite, got {value}")
        clean[key] = value
    missing = sorted(set(clean) - set(units))
    if missing:
        raise ValueError(f"no unit for {missing}")
    data: dict[str, Any] = {"method": method, "gfjax_version": __version__,
                            "units": {k: units[k] for k in clean}, "values": clean}
    for key, value in (extra or {}).items():
        if key in data:
            raise ValueError(f"extra entry {key!r} would overwrite a params.json field")
        data[key] = value
    path = Path(path)
    text = json.dumps(data, indent=2, sort_keys=False, default=_jsonable) + "\n"
    with atomic_output(path, force=True, suffixes=(".json",)) as tmp:
        tmp.write_text(text)
    return path


def _jsonable(value):
    if isinstance(value, (np.generic, jax.Array)):
        return np.asarray(value).tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


