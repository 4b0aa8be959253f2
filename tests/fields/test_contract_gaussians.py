"""Tests of Gaussians through nerf_jax.fields.contraction (contract_gaussian and its diagonal and
isotropic forms) against references written here: the closed form of contract in float64, its
Jacobian by central differences, and a Monte Carlo of contracted samples.

jax_debug_nans is on for the whole module: a NaN anywhere, a backward pass included, fails.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

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
  # The diagonal form: (J∘J)·var, >= 0 exactly, the diagonal of the full one for diagonal cov.
  var = np.float32(np.diagonal(covs, axis1=-2, axis2=-1))
  mean_d, var_out = contraction.contract_gaussian_diagonal(means, var, RADIUS, kind)
  np.testing.assert_array_equal(mean_d, contraction.contract(means, RADIUS, kind))
  assert np.all(np.asarray(var_out) >= 0.0) and np.all(np.isfinite(var_out))
  _, full = contraction.contract_gaussian(means, var[..., None] * np.eye(3, dtype=np.float32),
                                          RADIUS, kind)
  np.testing.assert_allclose(var_out, np.diagonal(full, axis1=-2, axis2=-1), rtol=1e-5,
                             atol=1e-30)


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
  var = jnp.diagonal(covs, axis1=-2, axis2=-1)
  std = jnp.full((8,), 0.01, jnp.float32)

  def full(m, c):
    mean, cov = contraction.contract_gaussian(m, c, RADIUS, kind)
    return jnp.sum(mean) + jnp.sum(cov)

  def diagonal(m, v):
    mean, out = contraction.contract_gaussian_diagonal(m, v, RADIUS, kind)
    return jnp.sum(mean) + jnp.sum(out)

  def isotropic(m, s):
    mean, out = contraction.contract_isotropic(m, s, RADIUS, kind)
    return jnp.sum(mean) + jnp.sum(out)

  for fn, second in ((full, covs), (diagonal, var), (isotropic, std)):
    value, grads = jax.value_and_grad(fn, argnums=(0, 1))(means, second)
    assert np.isfinite(value) and all(np.all(np.isfinite(g)) for g in grads), fn.__name__


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
