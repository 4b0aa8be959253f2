"""Cones: a pixel's footprint along its ray, as Gaussians (mip-NeRF) or as points (Zip-NeRF).

mip-NeRF (Barron et al. 2021) casts a cone instead of a line through each pixel; an interval
[t0, t1] of a ray is then a conical frustum, which it approximates by the Gaussian with the
frustum's mean and covariance (eq. 7-8 of the paper). Zip-NeRF (Barron et al. 2023) instead
stands six points in a hexagonal pattern for each frustum.

Conventions (cameras/rays.py): directions d are NOT normalised (camera-space z = -1), and t is
z-depth, so a ray's points are o + t·d. The cone has its apex at the origin o, its axis along
d, and at parameter t the radius `radius·t`, measured perpendicular to the ray: mip-NeRF's
convention, whose directions are un-normalised with z = -1 too. The density of a frustum's
points along t is then proportional to t^2 (the cross-section's area), whatever |d|.

Names and axes:
  origins, directions: float32 [..., 3]   the rays (world space)
  radii:               float32 [...]      base radius: the cone's radius at t = 1 (rays.base_radius)
  t0, t1:              float32 [..., S]   the S intervals of each ray, 0 <= t0 <= t1
  mean:                float32 [..., S, 3]
  cov:                 float32 [..., S, 3, 3] (full) or var: float32 [..., S, 3] (its diagonal)
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.cameras.rays import safe_normalize

# Squared lengths below this (lengths below ~1e-9) are treated as 0 before dividing by them:
# the division's gradient has 1/x^2, which overflows float32 for x < ~1e-19.
TINY_SQUARE = 1e-18

# Zip-NeRF's order of the hexagon's angles (in units of 60°): sum_j exp(i·theta_j) = 0 and
# sum_j j·exp(i·theta_j) = 0, so offsets proportional to t_j (affine in j) average to 0: the
# points' mean lies on the ray (see `multisamples`).
HEXAGON = np.array([0, 2, 4, 3, 5, 1]) * (np.pi / 3)
# camp_zipnerf's `unscented_scale_mult` (0.5 in its configs): the level weights read each
# multisample's scale halved, so a level fades where the cells reach half the cone's width, not
# one octave earlier (fields/field.Field.multisamples applies it).
UNSCENTED_SCALE_MULT = 0.5
# The six points' t as mean + std·HEX_T: j = 0..5 evenly spaced, scaled to mean 0, variance 1.
HEX_T = (np.arange(6) * 0.4 - 1.0) * np.sqrt(15.0 / 7.0)


def frustum_moments(t0, t1):
  """Moments of t, and of the radial offset, over the frustum between t0 and t1 (cone radius t).

  t0, t1: float32 [...], 0 <= t0 <= t1. Returns (t_mean, t_var, r_var), each float32 [...]:
  the mean and variance of t under the density proportional to t^2 on [t0, t1], and the
  per-axis variance of the offset perpendicular to the ray for a base radius of 1 (multiply by
  radius^2). mip-NeRF's stable form (its eq. 7) in the midpoint mu and half-width hw:
    t_mean = mu + 2·mu·hw^2 / (3 mu^2 + hw^2),
    t_var  = hw^2/3 - (4/15)·hw^4·(12 mu^2 - hw^2) / (3 mu^2 + hw^2)^2,
    r_var  = mu^2/4 + (5/12)·hw^2 - (4/15)·hw^4 / (3 mu^2 + hw^2).
  The quotients of the expanded moments, (t1^4 - t0^4)/(t1^3 - t0^3) and the like, cancel
  catastrophically when hw << mu; these do not. Exact for t0 = t1 (a disc: t_var = 0).
  """
  mu = 0.5 * (t0 + t1)
  hw = 0.5 * (t1 - t0)
  mu2, hw2 = mu * mu, hw * hw
  # ratio = hw^2 / (3 mu^2 + hw^2) lies in [0, 1]. The division's gradient has 1/denominator^2,
  # which overflows (and gives 0·inf = NaN at t0 = t1 = 0) for a denominator below ~1e-19: a
  # double where takes ratio = 0 there (intervals within ~1e-9 of the origin: points).
  denominator = 3.0 * mu2 + hw2
  nonzero = denominator > TINY_SQUARE
  ratio = jnp.where(nonzero, hw2 / jnp.where(nonzero, denominator, 1.0), 0.0)
  t_mean = mu * (1.0 + 2.0 * ratio)
  t_var = hw2 / 3.0 - (4.0 / 15.0) * ratio * ratio * (12.0 * mu2 - hw2)
  r_var = mu2 / 4.0 + (5.0 / 12.0) * hw2 - (4.0 / 15.0) * hw2 * ratio
  # Variances are >= 0; rounding can leave t_var a few ulps below 0 when hw ~ 0.
  return t_mean, jnp.maximum(t_var, 0.0), r_var


def lift_gaussian(directions, t_mean, t_var, r_var, diagonal=False):
  """The 3D Gaussian of a frustum from its moments along and across the ray (origin at 0).

  directions: float32 [..., 3]. t_mean, t_var, r_var: float32 [..., S] (r_var already times
  radius^2). diagonal: return only the covariance's diagonal.
  Returns (mean: float32 [..., S, 3], cov: float32 [..., S, 3, 3], or [..., S, 3] if diagonal):
  mean = t_mean·d, cov = t_var·d dᵀ + r_var·(I - d dᵀ/|d|^2): along the ray t varies with
  variance t_var (so the position by t_var·|d|^2), across it the offset has r_var per axis.
  """
  d = directions[..., None, :]  # [..., 1, 3]
  mean = t_mean[..., None] * d
  # A zero direction has no axis: a double where divides by 1 there (outer = 0, so the Gaussian
  # is isotropic, r_var) instead of 0, whose 1/|d|^4 in the gradient would be inf·0 = NaN.
  d_sq = jnp.sum(d * d, axis=-1, keepdims=True)
  d_sq = jnp.where(d_sq > TINY_SQUARE, d_sq, 1.0)
  if diagonal:
    dd = d * d
    return mean, t_var[..., None] * dd + r_var[..., None] * (1.0 - dd / d_sq)
  outer = d[..., :, None] * d[..., None, :]  # [..., 1, 3, 3]: elementwise, exact (no matmul)
  eye = jnp.eye(3, dtype=jnp.float32)
  cov = (t_var[..., None, None] * outer
         + r_var[..., None, None] * (eye - outer / d_sq[..., None]))
  return mean, cov


def frustum_gaussians(origins, directions, radii, t0, t1, diagonal=False):
  """mip-NeRF's Gaussian of each conical frustum.

  origins, directions: float32 [..., 3]. radii: float32 [...], base radii. t0, t1: float32
  [..., S]. diagonal: return the covariances' diagonals only (what the integrated positional
  encoding needs). Returns (mean: float32 [..., S, 3], cov: float32 [..., S, 3, 3], or
  [..., S, 3] if diagonal).
  """
  t_mean, t_var, r_var = frustum_moments(t0, t1)
  r_var = r_var * (radii * radii)[..., None]
  mean, cov = lift_gaussian(directions, t_mean, t_var, r_var, diagonal)
  return mean + origins[..., None, :], cov


def frustum_spreads(origins, directions, radii, t0, t1):
  """mip-NeRF's Gaussian of each conical frustum in the ray's own axes: its mean, and its
  variances along and across the ray, whose covariance `frustum_gaussians` forms as
  t_var·d dᵀ + r_var·(I - d dᵀ/|d|^2) (`lift_gaussian`).

  origins, directions: float32 [..., 3]. radii: float32 [...], base radii. t0, t1: float32
  [..., S]. Returns (mean: float32 [..., S, 3], `frustum_gaussians`' bit for bit; t_var:
  float32 [..., S], the variance of t; r_var: float32 [..., S], the offset's variance per axis
  across the ray, times radii^2). contraction.contract_frustum_gaussian takes them.
  """
  t_mean, t_var, r_var = frustum_moments(t0, t1)
  r_var = r_var * (radii * radii)[..., None]
  mean = t_mean[..., None] * directions[..., None, :]  # as lift_gaussian, op for op
  return mean + origins[..., None, :], t_var, r_var


def centre_samples(origins, directions, radii, t0, t1):
  """Each frustum's mean as one multisample (Zip-NeRF's level weighting without multisampling).

  origins, directions: float32 [..., 3]. radii: float32 [...]. t0, t1: float32 [..., S].
  Returns (points: float32 [..., S, 1, 3], scales: float32 [..., S, 1]): the point on the ray at
  the frustum's mean t, and the scale `multisamples` gives a point there (radius·t/sqrt(2)).
  """
  t_mean = frustum_moments(t0, t1)[0]
  points = origins[..., None, :] + t_mean[..., None] * directions[..., None, :]
  rho = (radii[..., None] * np.float32(math.sqrt(0.5))) * t_mean
  return points[..., None, :], rho[..., None]


def perpendicular_basis(directions):
  """Two unit vectors perpendicular to each direction and to each other.

  directions: float32 [..., 3], non-zero. Returns (a, b), each float32 [..., 3]. a is d crossed
  with the coordinate axis along which d is smallest, which is never within 54.7° of d, so the
  cross product never nearly vanishes; b = d̂ × a.
  """
  smallest = jnp.argmin(jnp.abs(directions), axis=-1)
  axis = jax.nn.one_hot(smallest, 3, dtype=directions.dtype)
  a = safe_normalize(jnp.cross(directions, axis))
  b = jnp.cross(safe_normalize(directions), a)
  return a, b


def multisamples(origins, directions, radii, t0, t1, key=None):
  """Zip-NeRF's six points per frustum, on a hexagon turned along the ray.

  origins, directions: float32 [..., 3]. radii: float32 [...]. t0, t1: float32 [..., S].
  key: None (deterministic: every other frustum's hexagon mirrored and turned by 30°, as
  Zip-NeRF does without a key) or a PRNG key (each hexagon mirrored at random and turned by a
  uniform random angle). Returns (points: float32 [..., S, 6, 3], scales: float32 [..., S, 6]).

  Point j sits at t_j = t_mean + sqrt(t_var)·HEX_T[j] along the ray (six even steps with the
  frustum's mean and variance of t: Zip-NeRF's closed form, rewritten in mip-NeRF's moments),
  at distance rho_j = radius·t_j/sqrt(2) from it (inside the cone), at angle HEXAGON[j] + turn.
  Its scale is rho_j, the isotropic standard deviation Zip-NeRF gives each multisample (before
  its `unscented_scale_mult`).

  Moments: the points' mean is the frustum Gaussian's exactly (sum_j t_j·exp(i·theta_j) = 0),
  their variance along the ray and their mean squared offset across it too (mean rho_j^2 / 2
  = r_var). The offsets' spread is not exactly isotropic and correlates slightly with t, since
  rho_j grows with t_j: the covariance differs from the Gaussian's by a relative O(hw/mu) (hw,
  mu: the interval's half-width and midpoint; tests/cameras/test_cones.py bounds it).
  """
  t_mean, t_var, _ = frustum_moments(t0, t1)  # r_var is matched through rho_j (see above)
  # sqrt'(0) is infinite: the floor keeps the gradient finite for zero-length intervals.
  t_std = jnp.sqrt(jnp.maximum(t_var, np.finfo(np.float32).tiny))
  t = t_mean[..., None] + t_std[..., None] * HEX_T.astype(np.float32)  # [..., S, 6]
  rho = (radii[..., None, None] * np.float32(math.sqrt(0.5))) * t
  thetas = jnp.asarray(HEXAGON, jnp.float32)
  frustums = t0.shape
  if key is None:
    flip = (jnp.arange(frustums[-1]) % 2 == 1)
    flip = jnp.broadcast_to(flip, frustums)
    turn = jnp.where(flip, np.float32(np.pi / 6), 0.0)
  else:
    flip_key, turn_key = jax.random.split(key)
    flip = jax.random.bernoulli(flip_key, shape=frustums)
    turn = jax.random.uniform(turn_key, frustums, jnp.float32, 0.0, 2.0 * np.pi)
  # Mirroring = the angles in reverse order; the balance conditions above hold either way.
  angles = jnp.where(flip[..., None], thetas[::-1], thetas) + turn[..., None]  # [..., S, 6]
  a, b = perpendicular_basis(directions)
  offset = (jnp.cos(angles)[..., None] * a[..., None, None, :]
            + jnp.sin(angles)[..., None] * b[..., None, None, :])
  points = (origins[..., None, None, :] + t[..., None] * directions[..., None, None, :]
            + rho[..., None] * offset)
  return points, rho

