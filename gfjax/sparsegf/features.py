"""Per-point input features of SparseGF's network.

Three sets (`Config.features`):

- `"xyz"`, the paper's: the point's compressed, patch-centred coordinates,
  `x / R_oc, y / R_oc, (z - patch mean) / Z_SCALE_M`, and a constant 1 (MinkowskiEngine's
  usual input). The paper does not list its input features; coordinates are what a
  MinkUNet is fed.
- `"xyz+tophat"`: those four, and the point's height above eight surfaces of the patch's
  lowest points: `z - zmin(cell)` and `z - opening_r(zmin)(cell)` for the grey openings of
  the 1 m minimum raster by squares of half-width `r` in `TOPHAT_RADII_PX` (3 m to 129 m
  wide). A morphological opening removes every object narrower than its window (Zhang et al.
  2003, the PMF), so the eight heights say how tall the point stands over the ground that a
  3 m ... 129 m window would see. They are computed on the patch's points before
  compression, thinning and rotation, so the periphery carries its true heights into the
  compressed context. Not in the paper: on 2 CPU cores and a few million labelled points the
  network does not learn these cues from coordinates alone (measured in
  `experiments/results/sparsegf_eval.md`).

- `"xyz+tophat+smrf"`: those twelve, and the point's height over SMRF's ground surface and
  SMRF's own margin (`gfjax.sparsegf.smrf_prior`), computed once per cloud on the host
  (`cloud_features`) and appended to the per-patch ones.

Heights enter as `sign(h) log(1 + |h| / 1 m)`: tens of metres and centimetres both matter.
Pure JAX (jit, vmap over patches).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from gfjax import raster
from gfjax.sparsegf.smrf_prior import N_SMRF_FEATURES, smrf_heights

FEATURE_SETS = ("xyz", "xyz+tophat", "xyz+tophat+smrf")
Z_SCALE_M = 10.0                               # patch-centred heights are divided by this [m]
TOPHAT_CELL_M = 1.0                            # cell of the minimum raster [m]
TOPHAT_RADII_PX = (1, 2, 4, 8, 16, 32, 64)     # half-widths of the opening squares [cells]


def reads_smrf(features: str) -> bool:
    """Whether a feature set has SMRF's per-cloud inputs."""
    return features.endswith("+smrf")


def n_features(features: str) -> int:
    """Input channels of a feature set."""
    if features not in FEATURE_SETS:
        raise ValueError(f"features must be one of {FEATURE_SETS}, got {features!r}")
    return patch_features(features) + (N_SMRF_FEATURES if reads_smrf(features) else 0)


def patch_features(features: str) -> int:
    """Input channels computed per patch (`programs.point_inputs`): the set's xyz and top-hat ones."""
    return 4 if features == "xyz" else 4 + 1 + len(TOPHAT_RADII_PX)


def cloud_features(xyz_m, features: str, *, smrf=None):
    """The inputs of a feature set that are computed once per cloud, `(n, e)` float32 already
    logged (`signed_log`), or None when the set has none. `xyz_m` `(n, 3)` [m], host numpy;
    `smrf`: the cloud's `smrf_prior.smrf_heights` when already computed."""
    if not reads_smrf(features):
        return None
    h = np.asarray(smrf_heights(xyz_m) if smrf is None else smrf, np.float64)
    # logged in float64, then rounded: numpy's float32 log1p takes another routine on a CPU with
    # AVX-512 (1-2 ulp apart on a tenth of samp12's values), so the inputs, and a model trained
    # on them, would depend on the machine; its float64 routines round to the same float32
    return (np.sign(h) * np.log1p(np.abs(h))).astype(np.float32)


def signed_log(h: Array) -> Array:
    """`sign(h) log(1 + |h|)`, h in metres."""
    return jnp.sign(h) * jnp.log1p(jnp.abs(h))


def xyz_features(xyz: Float[ArrayLike, "n 3"], valid: Bool[ArrayLike, " n"], *, r_oc_m: float) -> Float[Array, "n 4"]:
    """The paper's features `(n, 4)` of compressed points whose x, y are relative to the patch
    axis and z to the patch's mean height [m]; 0 on invalid rows."""
    f = jnp.stack([xyz[:, 0] / r_oc_m, xyz[:, 1] / r_oc_m, xyz[:, 2] / Z_SCALE_M, jnp.ones_like(xyz[:, 0])], axis=1)
    return jnp.where(valid[:, None], f, 0.0)


def tophat_surfaces(xyz: Float[Array, "n 3"], valid: Bool[Array, " n"], *,
                    half_extent_m: float) -> Float[Array, "s h w"]:
    """The minimum raster of the points and its openings, `(1 + len(TOPHAT_RADII_PX), h, w)`
    [m] over `[-half_extent_m, half_extent_m)^2` (1 m cells; `+inf` where the minimum raster
    is empty, `-inf` where an opening has no occupied cell in reach).

    Args:
      xyz: points `(n, 3)` [m], x and y relative to the patch axis (uncompressed).
      valid: `(n,)` bool; points outside the raster are ignored.
      half_extent_m: half the raster's side (static; the patch radius R_oo).
    """
    size = int(round(2 * half_extent_m / TOPHAT_CELL_M))
    cells = raster.rasterize(xyz[:, :2] + half_extent_m, xyz[:, 2], valid, cell_m=TOPHAT_CELL_M, shape=(size, size))
    openings = [raster.opening(cells.z_min, cells.valid, radius_px=r, footprint="square") for r in TOPHAT_RADII_PX]
    return jnp.stack([cells.z_min] + openings)


def heights_above(surfaces: Float[Array, "s h w"], xyz: Float[Array, "n 3"], valid: Bool[Array, " n"], *,
                  half_extent_m: float) -> Float[Array, "n s"]:
    """Each point's height over each surface at its cell `(n, s)` [m]; 0 for invalid points,
    points outside the raster, and cells a surface does not reach."""
    size = surfaces.shape[-1]
    row, col, inside = raster.cell_index(xyz[:, :2] + half_extent_m, cell_m=TOPHAT_CELL_M, shape=(size, size))
    row, col = jnp.clip(row, 0, size - 1), jnp.clip(col, 0, size - 1)
    under = surfaces[:, row, col].T                                        # (n, s)
    h = xyz[:, 2:3] - under
    return jnp.where((valid & inside)[:, None] & jnp.isfinite(under), h, 0.0)


@functools.partial(jax.jit, static_argnames=("half_extent_m",))
def tophat_heights(xyz: Float[Array, "n 3"], valid: Bool[Array, " n"], *,
                   half_extent_m: float) -> Float[Array, "n 8"]:
    """Heights `(n, 8)` [m] of each point over its cell's lowest point and over the openings
    of the minimum raster of the same points (module docstring); 0 on invalid rows.

    Args:
      xyz: points `(n, 3)` [m], x and y relative to the patch axis (uncompressed).
      valid: `(n,)` bool.
      half_extent_m: the raster covers `[-half_extent_m, half_extent_m)^2` (static; the
        patch radius R_oo). Points outside it are ignored and get 0.
    """
    surfaces = tophat_surfaces(xyz, valid, half_extent_m=half_extent_m)
    return heights_above(surfaces, xyz, valid, half_extent_m=half_extent_m)
