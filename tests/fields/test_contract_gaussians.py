"""Tests of Gaussians through nerf_jax.fields.contraction (contract_gaussian, the frustum's
diagonal form and the isotropic form) against references written here: the closed form of
contract in float64, its Jacobian by central differences, and a Monte Carlo of contracted
samples.

jax_debug_nans is on for the whole module: a NaN anywhere, a backward pass included, fails.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import cones
from nerf_jax.fields import contraction

pytestmark = pytest.mark.usefixtures("debug_nans")  # conftest.py: NaNs raise in this module

KINDS = contraction.KINDS
RADIUS = 1.5


def reference_contract(x, radius, kind):
  """float64 closed form: y = x/radius; radius·(y if |y| <= 1 else (2 - 1/|y|) y/|y|)."""
  y = np.asarray(x, np.float64) / radius
  n = (np.linalg.norm(y, axis=-1) if kind == "l2" else np.max(np.abs(y), axis=-1))[..., None]
  return radius * np.where(n <= 1.0, y, (2.0 - 1.0 / np.maximum(n, 1.0)) * y / np.maximum(n, 1.0))


def reference_jacobian(x, radius, kind, h=1e-6):
  """float64 [..., 3, 3] by central differences, step h·max(1, |x|)."""
  x = np.asarray(x, np.float64)
  step = h * np.maximum(1.0, np.linalg.norm(x, axis=-1))[..., None]
  cols = []
  for j in range(3):
    e = np.zeros(3)
    e[j] = 1.0
    cols.append((reference_contract(x + step * e, radius, kind)
                 - reference_contract(x - step * e, radius, kind)) / (2 * step))
  return np.stack(cols, axis=-1)


def random_gaussians(seed, num=300):
  """Means (norms log-uniform over 1e-3..1e6·RADIUS, plus the origin, 1e10 and 1e30) and random
  full covariances A Aᵀ (A's scale log-uniform over 1e-6..1e2, some of rank 1 and 2)."""
  rng = np.random.default_rng(seed)
  v = rng.normal(size=(num, 3))
  v /= np.linalg.norm(v, axis=-1, keepdims=True)
  means = v * RADIUS * 10.0 ** rng.uniform(-3, 6, (num, 1))
  means[:6] = [[0, 0, 0], [1e10, 0, 0], [-3e9, 4e9, 1e10], [1e30, -1e30, 2e29],
               [RADIUS, 0, 0], [0, 0, -RADIUS * 1.0000001]]
  a = rng.normal(size=(num, 3, 3)) * 10.0 ** rng.uniform(-6, 2, (num, 1, 1))
  a[::7, :, 1:] = 0.0  # rank 1
  a[1::7, :, 2] = 0.0  # rank 2
  return np.float32(means), np.float32(a @ np.swapaxes(a, -1, -2))


@pytest.mark.parametrize("kind", KINDS)
def test_mean_is_contract_and_jacobian_matches_differences(kind):
  means, covs = random_gaussians(0)
  mean, _ = contraction.contract_gaussian(means, covs, RADIUS, kind)
  np.testing.assert_array_equal(mean, contraction.contract(means, RADIUS, kind))
  jac = np.asarray(contraction.contraction_jacobian(means, RADIUS, kind))
  assert jac.shape == (300, 3, 3) and np.all(np.isfinite(jac))
  # Away from the inner boundary (a kink of the 'linf' norm's edges aside) and from float32's
  # range: differences of the float64 closed form, relative to J's largest entry.
  m64 = np.asarray(means, np.float64)
  norms = (np.linalg.norm(m64, axis=-1) if kind == "l2" else np.max(np.abs(m64), axis=-1))
  smooth = (np.abs(norms / RADIUS - 1.0) > 1e-3) & (norms < 1e8)
  if kind == "linf":  # the cube's edges: two coordinates tie for the largest
    top2 = np.sort(np.abs(means), axis=-1)[:, -2:]
    smooth &= (top2[:, 1] - top2[:, 0]) > 1e-3 * top2[:, 1]
  ref = reference_jacobian(means[smooth], RADIUS, kind)
  scale = np.max(np.abs(ref), axis=(-2, -1), keepdims=True)
  np.testing.assert_allclose(jac[smooth] / scale, ref / scale, rtol=0, atol=2e-5)
  np.testing.assert_array_equal(jac[0], np.eye(3))  # inside: the identity


@pytest.mark.parametrize("kind", KINDS)
def test_contracted_covariances_stay_positive_semi_definite(kind):
  means, covs = random_gaussians(1)
  _, out = contraction.contract_gaussian(means, covs, RADIUS, kind)
  out = np.asarray(out, np.float64)
  assert np.all(np.isfinite(out))
  np.testing.assert_array_equal(out, np.swapaxes(out, -1, -2))
  eig = np.linalg.eigvalsh(out)
  # float32 rounding: J cov Jᵀ is PSD exactly; its float32 value to ~1e-7 of its largest
  # eigenvalue (as cov's own float32 eigenvalues are).
  assert np.all(eig >= -1e-6 * np.maximum(eig[:, -1:], 1e-37)), eig.min()
  # Inside the inner region the covariance is unchanged (J = I).
  np.testing.assert_allclose(out[0], covs[0], rtol=1e-6, atol=0)
  # At 1e10 and 1e30 the contracted Gaussian has shrunk to ~cov·(2/|x|)^2 across the ray.
  assert np.all(np.abs(out[1:4]) <= 1e-12 * np.abs(covs[1:4]).max() + 1e-30)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("mean", [(2.0, -1.0, 0.5), (0.3, 5.0, 9.0), (-40.0, 3.0, 1.0)])
def test_covariance_matches_monte_carlo_of_contracted_samples(kind, mean):
  """A small Gaussian (std 1e-3 of |mean|): the linearisation's error is of relative order
  std·|contract''|/|contract'| ~ 1e-3 (curvature over the distance), well below the 5 standard
  errors of the Monte Carlo covariance, which bound the comparison entry by entry."""
  rng = np.random.default_rng(2)
  mean = np.asarray(mean, np.float64)
  a = rng.normal(size=(3, 3)) * 1e-3 * np.linalg.norm(mean)
  cov = a @ a.T
  x = rng.multivariate_normal(mean, cov, size=200_000)
  y = reference_contract(x, RADIUS, kind)
  c = y - y.mean(0)
  mc = c.T @ c / len(y)
  stderr = (c[:, :, None] * c[:, None, :]).std(0) / np.sqrt(len(y))
  got_mean, got = contraction.contract_gaussian(np.float32(mean), np.float32(cov), RADIUS, kind)
  scale = np.abs(mc).max()
  np.testing.assert_array_less(np.abs(got - mc), 5 * stderr + 2e-3 * scale)
  # The mean: contract(mean) against the samples' mean: 5 standard errors, plus the dropped
  # second-order term tr(H cov)/2 ~ 1e-3 of the spread (the curvature over the distance).
  np.testing.assert_array_less(np.abs(got_mean - y.mean(0)),
                               5 * np.sqrt(np.diag(mc) / len(y)) + 2e-3 * np.sqrt(scale))


@pytest.mark.parametrize("kind", KINDS)
def test_gradients_are_finite_at_the_origin_the_boundary_and_far_away(kind):
  means = jnp.float32([[0, 0, 0], [1e-30, 0, 0], [RADIUS, 0, 0], [RADIUS, RADIUS, 0],
                       [1e10, 0, 0], [-3e9, 4e9, 1e10], [1e30, 2e30, -1e30], [0.3, -0.2, 0.1]])
  covs = jnp.broadcast_to(jnp.float32([[2.0, 0.3, 0.1], [0.3, 1.0, 0.2], [0.1, 0.2, 0.5]]),
                          (8, 3, 3)) * 1e-2
  std = jnp.full((8,), 0.01, jnp.float32)

  def full(m, c):
    mean, cov = contraction.contract_gaussian(m, c, RADIUS, kind)
    return jnp.sum(mean) + jnp.sum(cov)

  def isotropic(m, s):
    mean, out = contraction.contract_isotropic(m, s, RADIUS, kind)
    return jnp.sum(mean) + jnp.sum(out)

  for fn, second in ((full, covs), (isotropic, std)):
    value, grads = jax.value_and_grad(fn, argnums=(0, 1))(means, second)
    assert np.isfinite(value) and all(np.all(np.isfinite(g)) for g in grads), fn.__name__

  # The frustums' form, w.r.t. every input: oblique and axis-aligned rays, a zero direction,
  # a needle (r_var = 0) and a point (both 0), out to 1e30.
  dirs = jnp.float32([[0.8, -0.5, 0.45], [1, 0, 0], [0, 0, 0], [-0.3, 0.4, 1.0],
                      [1, 0, 0], [-3, 4, 10], [1, 2, -1], [0.8, -0.5, 0.45]])
  t_var = jnp.float32([1e-2, 0.0, 1.0, 1e3, 1e6, 1e2, 1e10, 1e-4])
  r_var = jnp.float32([1e-4, 0.0, 1.0, 0.0, 1e-2, 1e-6, 1e4, 1e-6])

  def frustum(m, d, a, b):
    mean, out = contraction.contract_frustum_gaussian(m, d, a, b, RADIUS, kind)
    return jnp.sum(mean) + jnp.sum(out)

  value, grads = jax.value_and_grad(frustum, argnums=(0, 1, 2, 3))(means, dirs, t_var, r_var)
  assert np.isfinite(value) and all(np.all(np.isfinite(g)) for g in grads)


@pytest.mark.parametrize("kind", KINDS)
def test_isotropic_scale_is_the_cube_root_of_the_jacobian_determinant(kind):
  means, _ = random_gaussians(3)
  std = np.float32(np.random.default_rng(3).uniform(0.01, 1.0, len(means)))
  mean, out = contraction.contract_isotropic(means, std, RADIUS, kind)
  np.testing.assert_array_equal(mean, contraction.contract(means, RADIUS, kind))
  out = np.asarray(out, np.float64)
  assert np.all(np.isfinite(out)) and np.all(out >= 0.0)
  assert np.all(out[np.abs(means).max(-1) < 1e20] > 0.0)
  np.testing.assert_allclose(out[0], std[0], rtol=1e-6)  # inside: unchanged
  n = (np.linalg.norm(np.asarray(means, np.float64), axis=-1) if kind == "l2"
       else np.max(np.abs(np.asarray(means, np.float64)), axis=-1))
  outside = n > RADIUS
  n = np.maximum(n, RADIUS)  # the closed form of the outside (inside, the scale is 1)
  if kind == "l2":  # J's eigenvalues: radial R^2/|x|^2, tangential (twice) R(2 - R/|x|)/|x|
    det = (RADIUS / n) ** 2 * (RADIUS * (2 - RADIUS / n) / n) ** 2
    # (1e-40 at |x| ~ 1e30 is below float32's normal range: flushed to 0 on a CPU)
    np.testing.assert_allclose(out, np.where(outside, std * np.cbrt(det), std), rtol=1e-5,
                               atol=1e-37)
  # Against the determinant of the differences' Jacobian (float64), away from the inner
  # boundary and from the cube's edges, and where the differences resolve J (|x| < 1e4).
  top2 = np.sort(np.abs(np.asarray(means, np.float64)), axis=-1)[:, -2:]
  ok = (np.abs(n / RADIUS - 1.0) > 1e-3) & (n < 1e4)
  if kind == "linf":
    ok &= (top2[:, 1] - top2[:, 0]) > 1e-3 * top2[:, 1]
  det = np.abs(np.linalg.det(reference_jacobian(means[ok], RADIUS, kind)))
  np.testing.assert_allclose(out[ok], std[ok] * np.cbrt(det), rtol=1e-4)
  assert out[3] < 1e-30  # |x| ~ 1e30: (2/|x|^2)^(1/3)·... ~ 1e-40, finite


# mip-NeRF 360's contracted frustum Gaussians (contract_frustum_gaussian, what the Field uses):
# the full covariance through J, against a Monte Carlo of the Gaussian's samples pushed through
# `contract`, on rays oblique to the axes far outside the inner region. The cases: (distance of
# the frustum's start along the ray, t1/t0, base radius). Thin cones and long intervals make
# the Gaussian a needle along the ray (t_var/r_var from ~130 to ~3e4), which the contraction
# squeezes by its radial ~1/|x|^2; Σ's diagonal alone spreads the needle over every axis,
# squeezed only by the tangential ~1/|x| (27x to 3e4x too large, measured here).
FRUSTUMS = [(10.0, 1.02, 1e-3), (100.0, 1.02, 1e-4), (1e4, 1.05, 1e-4)]
OBLIQUE = np.float32([0.8, -0.5, 0.45])  # a ray direction (un-normalised) off every axis


def frustum_covariance(directions, t_var, r_var):
  """float64 [3, 3]: t_var·d dᵀ + r_var·(I - d dᵀ/|d|^2), written out."""
  d = np.asarray(directions, np.float64)
  dd = np.outer(d, d)
  return t_var * dd + r_var * (np.eye(3) - dd / (d @ d))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("distance, stretch, base_radius", FRUSTUMS)
def test_frustum_gaussian_matches_monte_carlo_and_the_diagonal_form_does_not(
    kind, distance, stretch, base_radius):
  """Tolerance: 5 standard errors of the Monte Carlo variance plus 1% (the linearisation's
  error is of relative order (std/distance)^2·(curvature)^2 < 1e-3 here; measured: within
  0.75%). The old form (the diagonal of Σ through J) is more than 20x too large on some axis."""
  origin = np.float32([0.3, -0.2, 0.1])
  t0 = np.float32([distance / np.linalg.norm(OBLIQUE)])
  mean, t_var, r_var = cones.frustum_spreads(origin, OBLIQUE, np.float32(base_radius), t0,
                                             t0 * np.float32(stretch))
  mean, t_var, r_var = mean[0], t_var[0], r_var[0]
  cov = frustum_covariance(OBLIQUE, float(t_var), float(r_var))
  rng = np.random.default_rng(4)
  x = rng.multivariate_normal(np.asarray(mean, np.float64), cov, size=200_000)
  y = np.asarray(contraction.contract(np.float32(x), RADIUS, kind), np.float64)
  c = y - y.mean(0)
  mc = np.mean(c * c, axis=0)
  stderr = np.std(c * c, axis=0) / np.sqrt(len(y))
  got_mean, got = contraction.contract_frustum_gaussian(mean, OBLIQUE, t_var, r_var, RADIUS,
                                                        kind)
  np.testing.assert_array_equal(got_mean, contraction.contract(mean, RADIUS, kind))
  np.testing.assert_array_less(np.abs(np.asarray(got, np.float64) - mc), 5 * stderr + 1e-2 * mc)
  # The former form: the covariance cut to its diagonal first, then (J∘J)·var.
  jac = np.asarray(contraction.contraction_jacobian(np.float32(mean), RADIUS, kind), np.float64)
  old = np.sum(jac * jac * np.diag(cov), axis=-1)
  assert np.max(old / mc) > 20.0


@pytest.mark.parametrize("kind", KINDS)
def test_frustum_gaussian_is_the_diagonal_of_the_full_form(kind):
  """Against diag(J Σ Jᵀ) with Σ written out and the product taken in float64 (J the library's
  contraction_jacobian), over random means from the origin to 1e6·RADIUS and beyond, random
  directions (one zero: Σ isotropic) and variances, needles (r_var = 0) among them; >= 0
  exactly. (In float32 the full product is the less accurate one: for a needle far out, the
  rounding of Σ's large t_var·d dᵀ, ~1e-7 of it, reaches the axes J squeezes only by 1/|x|.)"""
  means, _ = random_gaussians(5)
  rng = np.random.default_rng(5)
  dirs = np.float32(rng.normal(size=means.shape) * 10.0 ** rng.uniform(-1, 1, (len(means), 1)))
  dirs[7] = 0.0
  t_var = np.float32(10.0 ** rng.uniform(-6, 2, len(means)))
  r_var = np.float32(10.0 ** rng.uniform(-6, 2, len(means)))
  r_var[::5] = 0.0  # a ray of radius 0: a needle
  mean, var = contraction.contract_frustum_gaussian(means, dirs, t_var, r_var, RADIUS, kind)
  np.testing.assert_array_equal(mean, contraction.contract(means, RADIUS, kind))
  var = np.asarray(var, np.float64)
  assert np.all(np.isfinite(var)) and np.all(var >= 0.0)
  cov = np.stack([frustum_covariance(d, a, b) if np.any(d) else b * np.eye(3)
                  for d, a, b in zip(dirs, t_var, r_var)])
  jac = np.asarray(contraction.contraction_jacobian(means, RADIUS, kind), np.float64)
  want = np.einsum("nij,njk,nik->ni", jac, cov, jac)
  # Each term of the float32 sums is rounded to ~1e-7 relative: compared to the largest term,
  # (J∘J)·(t_var·|d|^2 + r_var), per axis.
  scale = np.sum(jac * jac, axis=-1) * (t_var * np.sum(np.float64(dirs) ** 2, -1) + r_var)[:, None]
  np.testing.assert_array_less(np.abs(var - want), 1e-5 * scale + 1e-37)
