"""Relaxed threshold tests (SPEC section 7): `sigmoid((h - t) / temperature)` for `h > t`.

Every hard test of a filter, `h > t` or `h <= t`, has a relaxed form whose value is the
probability-like weight `sigmoid(margin / temperature)` of the test being true. With
`temperature=None` the functions return the hard boolean test itself, computed with the
same floating-point expression as the plain filter, so a pipeline built on them reproduces
the plain filter bit for bit. As `temperature -> 0` the relaxed form tends to the hard one
(except exactly at the threshold, where it is 1/2).

All arguments broadcast explicitly (same shapes, or scalars); heights and thresholds in
metres, the temperature in the same unit as the margin (metres for the filters here).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

__all__ = ["greater", "less_equal", "soft_or_max", "geometric_schedule"]


def _check_temperature(temperature) -> None:
    if isinstance(temperature, (int, float)) and not temperature > 0:
        raise ValueError(f"temperature must be > 0 (or None for the hard test), got {temperature}")


def greater(h: Float[ArrayLike, ...], t: Float[ArrayLike, ...],
            temperature: float | Float[ArrayLike, ""] | None = None) -> Bool[Array, ...] | Float[Array, ...]:
    """`h > t`: hard bool with `temperature=None`, else `sigmoid((h - t) / temperature)`.

    Args:
      h: tested values, e.g. the drop of a cell under an opening [m].
      t: thresholds, same shape as `h` or scalar [m].
      temperature: softness [m] (> 0, may be traced), or None for the hard test.

    Returns:
      bool (hard) or float in (0, 1) of `h`'s dtype (relaxed), shape of `h`.
    """
    if temperature is None:
        return h > t
    _check_temperature(temperature)
    return jax.nn.sigmoid((h - t) / temperature)


def less_equal(h: Float[ArrayLike, ...], t: Float[ArrayLike, ...],
               temperature: float | Float[ArrayLike, ""] | None = None) -> Bool[Array, ...] | Float[Array, ...]:
    """`h <= t`: hard bool with `temperature=None`, else `sigmoid((t - h) / temperature)`."""
    if temperature is None:
        return h <= t
    _check_temperature(temperature)
    return jax.nn.sigmoid((t - h) / temperature)


def soft_or_max(margins: Float[ArrayLike, "k ..."], temperature: float | Float[ArrayLike, ""] | None = None,
                *, axis: int = 0) -> Bool[Array, ...] | Float[Array, ...]:
    """`any(margins > 0)` along `axis`: hard bool, or `sigmoid(max(margins) / temperature)`.

    The relaxed OR of several threshold tests `h_k > t_k` (margins `h_k - t_k`) as the
    largest relaxed test (sigmoid is increasing). Unlike a noisy-OR `1 - prod(1 - p_k)`, it
    does not saturate towards 1 when many tests are each a little likely at a high
    temperature. The gradient flows to the test with the largest margin.
    """
    if temperature is None:
        return jnp.any(margins > 0, axis=axis)
    _check_temperature(temperature)
    return jax.nn.sigmoid(jnp.max(margins, axis=axis) / temperature)


def geometric_schedule(start: float, end: float, steps: int) -> Float[Array, " steps"]:
    """Temperatures annealed geometrically from `start` to `end` over `steps` steps (float32).

    E.g. 1 m -> 0.05 m (SPEC section 7). `steps == 1` gives `[end]`.
    """
    if not (start > 0 and end > 0):
        raise ValueError(f"temperatures must be > 0, got start={start}, end={end}")
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    if steps == 1:
        return jnp.asarray([end], jnp.float32)
    return jnp.geomspace(start, end, steps).astype(jnp.float32)
