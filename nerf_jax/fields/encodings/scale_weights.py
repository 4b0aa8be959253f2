"""Zip-NeRF's scale-aware weights of grid levels (Barron et al. 2023, section 2).

A sample that stands for a Gaussian of standard deviation sigma should not read a grid level
whose cells are much smaller than sigma: the features of those cells alias. Zip-NeRF weights
each level's features by the fraction of the Gaussian's mass, along one axis, inside a cell
centred at its mean:
  w_l = P(|X| < h_l / 2) for X ~ N(0, sigma^2) = erf(h_l / (sqrt(8)·sigma)),
h_l the level's cell size. In the unit box with n_l cells per side (h_l = 1/n_l) this is
erf(1 / sqrt(8 sigma^2 n_l^2)), Zip-NeRF's form. w -> 1 for points (sigma -> 0) and -> 0 for
Gaussians much wider than a cell.

Cells: grid.py and hash.py put R_l lattice points per side over the box, i.e. R_l - 1 cells
(`to_unit_cube` maps [-bound, bound] to [0, 1]: n_l = R_l - 1 cells over the side 2·bound, or
over each side of a `to_unit_box` box with cubic cells, `axis_resolutions`). So in world units
h_l = side / (R_l - 1): `cell_sizes`. sigma and h must be in the same units (world, or
contracted space for a grid over contracted space: contraction.contract_isotropic).

The scale of an anisotropic Gaussian (`isotropic_std`): det(cov)^(1/6), the standard deviation
of the isotropic Gaussian of the same volume, as Zip-NeRF's contraction of scales keeps volume
(|det J|^(1/3)); so isotropic_std(J cov Jᵀ) = |det J|^(1/3)·isotropic_std(cov) exactly, and
the scale of a contracted Gaussian does not depend on whether it was taken before or after.

Names and axes:
  std:        float32 [...]        a Gaussian's (isotropic) standard deviation, >= 0
  cells:      float32 [L]          each level's cell size, > 0 (`cell_sizes`)
  weights:    float32 [..., L]     in [0, 1]
"""

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erf

# Variances below this (std < 1e-15, far below any cell) make a point: std 0.
MIN_VARIANCE = 1e-30
# The smallest variance ratio (to the largest) that isotropic_std resolves: flatter Gaussians
# count as this flat (std >= 1e-4·the largest std), which bounds the gradient.
MIN_FLATNESS = 1e-12

# erf(x) rounds to 1 in float32 for x >= ~3.9, and its derivative there is 2/sqrt(pi)·exp(-x^2)
# < 1e-6; past x = 10, exp(-100) is 0 in float32. Arguments are clamped here (see level_weights).
MAX_ERF_ARGUMENT = 10.0


def cell_sizes(resolutions, side):
  """Cell size of each level: side / (R_l - 1), float32 [L] (numpy).

  resolutions: ints R_l >= 2, lattice points per side of each level (hashgrid.level_resolutions,
  or one dense grid's). side: float > 0, the box side they span (2·bound for to_unit_cube; 1 for
  unit-box coordinates).
  """
  res = np.asarray(resolutions, np.float64)
  if np.any(res < 2):
    raise ValueError(f"grid levels need at least 2 lattice points per side, got {resolutions}")
  return np.float32(side / (res - 1.0))


def level_weights(std, cells):
  """Zip-NeRF's weight of each level for a Gaussian of standard deviation std.

  std: float32 [...], >= 0 (0: a point; inf allowed). cells: float32 [L], > 0, each level's
  cell size (`cell_sizes`) in std's units. Returns float32 [..., L]: erf(h_l / (sqrt(8)·std)),
  1 at std = 0, 0 at std = inf.
  Numerics: h/(sqrt(8)·std) is infinite at std = 0, and its derivative -h/(sqrt(8)·std^2)
  meets erf's derivative exp(-inf) = 0 as inf·0 = NaN in the gradient. std is floored at
  h/(sqrt(8)·MAX_ERF_ARGUMENT), where erf is already exactly 1 (its true derivative below
  exp(-100)), so values are unchanged and the gradient is 0 below the floor. std = inf gives
  argument 0, erf(0) = 0, gradient -h/inf = 0.
  """
  std = jnp.asarray(std, jnp.float32)[..., None]
  h = jnp.asarray(cells, jnp.float32) / np.float32(np.sqrt(8.0))
  return erf(h / jnp.maximum(std, h / MAX_ERF_ARGUMENT))


def isotropic_std(cov):
  """The standard deviation of the isotropic Gaussian with cov's volume: det(cov)^(1/6).

  cov: float32 [..., 3, 3], positive semi-definite. Returns float32 [...], >= 0.
  Numerics: with m the largest variance (the largest entry of a PSD matrix), det(cov)^(1/6) =
  det(cov/m)^(1/6)·sqrt(m), and det(cov/m) in [0, 1] neither underflows (variances ~1e-20 in
  contracted space: det ~1e-60) nor overflows. m is a constant to the gradient
  (stop_gradient: the expression is the same for every m, so the gradient is exact), whose
  1/m^2 would overflow for small m. det by the triple product, a polynomial (jnp.linalg.det's
  gradient solves with cov: NaN where it is singular). Two floors keep the gradient,
  (1/6)·std·cov^-1, finite (below ~1e35): m < MIN_VARIANCE counts as a point (std 0), and
  det(cov/m) is floored at MIN_FLATNESS^2, so a flat Gaussian (a disc, a segment) gets std
  1e-4·sqrt(m) rather than 0 (its weights are those of a Gaussian 1e-4 of its size).
  """
  m = jax.lax.stop_gradient(jnp.max(jnp.diagonal(cov, axis1=-2, axis2=-1), axis=-1))
  point = m < MIN_VARIANCE
  safe_m = jnp.where(point, 1.0, m)
  c = cov / safe_m[..., None, None]
  det = jnp.sum(c[..., 0, :] * jnp.cross(c[..., 1, :], c[..., 2, :]), axis=-1)
  det = jnp.maximum(det, MIN_FLATNESS ** 2)  # also rounding, which can make a flat det < 0
  return jnp.where(point, 0.0, jnp.exp(jnp.log(det) / 6.0) * jnp.sqrt(safe_m))


def isotropic_std_diagonal(var):
  """`isotropic_std` of a diagonal covariance: (var_x·var_y·var_z)^(1/6).

  var: float32 [..., 3], >= 0. Returns float32 [...], >= 0: the geometric mean of the three
  standard deviations. Numerics: as isotropic_std, relative to the largest variance m (a
  constant to the gradient); each ratio is floored at MIN_FLATNESS before its log (log 0 =
  -inf), which bounds the gradient std/(6·var_i) by ~1e27.
  """
  m = jax.lax.stop_gradient(jnp.max(var, axis=-1))
  point = m < MIN_VARIANCE
  safe_m = jnp.where(point, 1.0, m)
  rel = jnp.maximum(var / safe_m[..., None], MIN_FLATNESS)
  return jnp.where(point, 0.0, jnp.exp(jnp.mean(jnp.log(rel), axis=-1) / 2.0) * jnp.sqrt(safe_m))
