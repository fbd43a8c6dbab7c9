"""Convex-mirror context compression of a cylindrical patch (Qin et al. 2026, Sec. 2.1, Eqs. 1-3).

A patch is a cylinder of radius `R_oo` about a vertical axis through `c = (X_c, Y_c)`. Points
within the inner invariant radius `R_in` of the axis stay where they are (the *central*
region, the only one the network classifies). Points in the compression zone
`R_in < r <= R_oo` slide towards the axis along their own direction, linearly in `r`, so
that the outer original boundary `R_oo` lands on the outer compressed boundary `R_oc`:

    r' = R_in + k * (r - R_in),      k = (R_oc - R_in) / (R_oo - R_in)          (radial form)

Heights are never changed (Eq. 3). The paper writes the same map per coordinate (Eqs. 1-2):

    X' = k * X + (1 - k) * (R_in * (X - X_c) / r + X_c)

which, rearranged about the centre, is `p' = c + s(r) * (p - c)` with the scale
`s(r) = k + (1 - k) * R_in / r`. This module evaluates that centred form: it is
algebraically Eq. 1-2 but keeps float32 precision when the coordinates are far from the
origin, and its gradient is finite everywhere (the square root is only evaluated at
`r >= R_in > 0`, so the kink at `r = 0` of `|p - c|` is never differentiated).

Defaults (Sec. 3.3): R_oo = 150 m (the partition's cylinder radius), R_oc = 44 m,
R_in = 25 * sqrt(2) m (= step * sqrt(2) / 2 for the 50 m step of the partition).
Pure JAX; no scipy.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike
from jaxtyping import Array, Bool, Float

R_OO_M = 150.0                   # outer original radius R_oo [m] (Sec. 3.3)
R_OC_M = 44.0                    # outer compressed radius R_oc [m] (Sec. 3.3)
R_IN_M = 25.0 * math.sqrt(2.0)   # inner invariant radius R_in [m] (Sec. 3.3)
CENTRAL_TOL_M = 1e-4             # a point this close outside R_in still counts as central [m]


class Compressed(NamedTuple):
    """What `compress` returns for one patch.

    Attributes:
      xyz: compressed coordinates `(n, 3)`, float32 metres, same frame as the input.
      central: `(n,)` bool, the point lies in the central region `r <= R_in` (to within
        `CENTRAL_TOL_M`) and is valid: the points the network classifies and scores.
    """

    xyz: Float[Array, "n 3"]
    central: Bool[Array, " n"]


def compression_ratio(*, r_in: float, r_oc: float, r_oo: float) -> float:
    """`k = (R_oc - R_in) / (R_oo - R_in)`, the radial slope in the compression zone [-]."""
    return (r_oc - r_in) / (r_oo - r_in)


def _check_radii(r_in, r_oc, r_oo) -> None:
    values = (r_in, r_oc, r_oo)
    if not all(isinstance(v, (int, float)) for v in values):
        return  # traced radii (e.g. tuned by optax): checked by the caller
    if not 0.0 < r_in < r_oc <= r_oo:
        raise ValueError(f"compress: need 0 < r_in < r_oc <= r_oo [m], got r_in={r_in}, "
                         f"r_oc={r_oc}, r_oo={r_oo}")


def compress(xyz: Float[ArrayLike, "n 3"], center: Float[ArrayLike, 2], *,
             r_in: float | Float[Array, ""] = R_IN_M, r_oc: float | Float[Array, ""] = R_OC_M,
             r_oo: float | Float[Array, ""] = R_OO_M, valid: Bool[ArrayLike, " n"] | None = None) -> Compressed:
    """Compress the periphery of one cylindrical patch towards its axis (Eqs. 1-3).

    Args:
      xyz: points `(n, 3)`, float32 metres (any horizontal frame; for precision, prefer
        coordinates relative to the patch centre, as `PatchBatch.local_xyz` gives).
      center: the patch axis `(X_c, Y_c)`, shape `(2,)`, float32 metres, same frame.
      r_in: inner invariant radius R_in [m]; points with `r <= r_in` are unchanged.
      r_oc: outer compressed radius R_oc [m]; the image of `r_oo`.
      r_oo: outer original radius R_oo [m]. Points beyond it (none, in a partition patch)
        follow the same linear law, so `r' > r_oc`; they are not clamped.
      valid: optional `(n,)` bool; padding rows get `central = False` (their coordinates
        are mapped like any other point and should be ignored).

    Returns:
      `Compressed(xyz, central)`: `xyz` `(n, 3)` float32 with `z` unchanged (Eq. 3) and
      `(x, y)` mapped by Eqs. 1-2; `central` `(n,)` bool, `r <= r_in + CENTRAL_TOL_M` and
      valid. The tolerance (0.1 mm) makes the central regions of the 50 m grid cover
      points lying exactly on a cell corner, at distance `R_in` from four centres, whatever
      the float32 rounding; such a point is displaced by less than `0.1 * (1 - k)` mm.

    The map is continuous, radially monotone (slope 1 inside, `k` outside), keeps each
    point's direction from the axis, sends `r_oo` to `r_oc`, and is differentiable except
    on the circle `r = r_in` (where jax.grad returns the inside, identity, derivative).
    One patch per call; batch with `jax.vmap(compress)`. Works under `jax.jit`.
    """
    xyz, center = jnp.asarray(xyz), jnp.asarray(center)
    valid = None if valid is None else jnp.asarray(valid)
    if xyz.ndim != 2 or xyz.shape[-1] != 3:
        raise ValueError(f"compress: xyz must have shape (n, 3), got {xyz.shape}")
    if center.shape != (2,):
        raise ValueError(f"compress: center must have shape (2,), got {center.shape}")
    if valid is not None and valid.shape != xyz.shape[:1]:
        raise ValueError(f"compress: valid must have shape {xyz.shape[:1]}, got {valid.shape}")
    _check_radii(r_in, r_oc, r_oo)
    return _compress(xyz, center, r_in, r_oc, r_oo, valid)


@jax.jit
def _compress(xyz, center, r_in, r_oc, r_oo, valid):
    k = (r_oc - r_in) / (r_oo - r_in)
    d_xy = xyz[:, :2] - center[None, :]                      # p - c, (n, 2) [m]
    r_sq = jnp.sum(d_xy * d_xy, axis=1)                       # (n,) [m^2]
    outside = r_sq > r_in * r_in                              # compression zone (Eqs. 1-2)
    r_safe = jnp.sqrt(jnp.where(outside, r_sq, r_in * r_in))  # >= r_in > 0: finite gradients
    scale = k + (1.0 - k) * r_in / r_safe                     # s(r) = r' / r outside R_in
    xy = jnp.where(outside[:, None], center[None, :] + scale[:, None] * d_xy, xyz[:, :2])
    out = jnp.concatenate([xy, xyz[:, 2:]], axis=1)          # z unchanged (Eq. 3)
    r_tol = r_in + CENTRAL_TOL_M
    central = r_sq <= r_tol * r_tol
    if valid is not None:
        central = central & valid
    return Compressed(out.astype(xyz.dtype), central)
