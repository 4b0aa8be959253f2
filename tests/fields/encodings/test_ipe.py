"""Tests of nerf_jax.fields.encodings.ipe against references written here (float64).

jax_debug_nans is on for the whole module: a NaN anywhere, a backward pass included, fails.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import cones
from nerf_jax.fields.encodings.posenc import coarse_to_fine_weights, positional_encoding
from nerf_jax.fields.encodings.ipe import band_damping, integrated_positional_encoding

pytestmark = pytest.mark.usefixtures("debug_nans")  # conftest.py: NaNs raise in this module


def point_encoding(x, num_freqs):
  """The point encoding's bands in float64: [..., L, 2d] = [sin(2^k x), cos(2^k x)] per band."""
  s = x[..., None, :] * 2.0 ** np.arange(num_freqs)[:, None]
  return np.concatenate([np.sin(s), np.cos(s)], axis=-1)


def frustum_samples(rng, origin, direction, radius, t0, t1, num):
  """float64 [num, 3]: points uniform in the conical frustum (density ∝ t^2 along the ray, a
  uniform disc of radius radius·t across it; d un-normalised, t z-depth)."""
  u, v, phi = rng.uniform(size=(3, num))
  t = np.cbrt(t0 ** 3 + u * (t1 ** 3 - t0 ** 3))
  d = np.asarray(direction, np.float64)
  e1 = np.cross(d, [0.6, 0.0, 0.8])
  e1 /= np.linalg.norm(e1)
  e2 = np.cross(d / np.linalg.norm(d), e1)
  rho = radius * t * np.sqrt(v)
  offset = rho[:, None] * (np.cos(2 * np.pi * phi)[:, None] * e1
                           + np.sin(2 * np.pi * phi)[:, None] * e2)
  return np.asarray(origin, np.float64) + t[:, None] * d + offset


@pytest.mark.parametrize("num_freqs", [0, 1, 4, 10, 16])
def test_zero_variance_is_the_point_encoding_bit_for_bit(num_freqs):
  x = jax.random.uniform(jax.random.PRNGKey(0), (7, 5, 3), jnp.float32, -3.0, 3.0)
  zero = jnp.zeros_like(x)
  np.testing.assert_array_equal(integrated_positional_encoding(x, zero, num_freqs),
                                positional_encoding(x, num_freqs))
  if num_freqs:
    weights = coarse_to_fine_weights(jnp.float32(num_freqs / 2 + 0.3), num_freqs)
    np.testing.assert_array_equal(integrated_positional_encoding(x, zero, num_freqs, weights),
                                  positional_encoding(x, num_freqs, weights))


def test_layout_and_gaussian_closed_form():
  """Against E[sin(w x)] = sin(w m) exp(-w^2 v/2) for x ~ N(m, v), feature by feature in
  positional_encoding's order, and against a Monte Carlo of Gaussian samples (5 standard
  errors)."""
  rng = np.random.default_rng(0)
  mean = rng.uniform(-2, 2, (4, 3))
  var = rng.uniform(0, 0.05, (4, 3)) ** 2
  num_freqs = 6
  weights = np.float32([1.0, 1.0, 0.9, 0.5, 0.1, 0.0])
  got = np.asarray(integrated_positional_encoding(np.float32(mean), np.float32(var), num_freqs,
                                                  weights))
  assert got.shape == (4, 3 + 6 * num_freqs)
  w = 2.0 ** np.arange(num_freqs)[:, None]
  damp = np.exp(-0.5 * w ** 2 * var[:, None, :])  # [4, L, 3]
  bands = np.concatenate([np.sin(w * mean[:, None]) * damp, np.cos(w * mean[:, None]) * damp],
                         axis=-1) * weights[:, None]
  expected = np.concatenate([mean, bands.reshape(4, -1)], axis=-1)
  np.testing.assert_allclose(got, expected, rtol=0, atol=2e-6)
  samples = mean + np.sqrt(var) * rng.normal(size=(100_000, 4, 3))
  mc = point_encoding(samples, num_freqs) * weights[:, None]
  mc_mean = np.concatenate([samples.mean(0), mc.mean(0).reshape(4, -1)], axis=-1)
  mc_err = np.concatenate([samples.std(0), mc.std(0).reshape(4, -1)], axis=-1) / np.sqrt(1e5)
  np.testing.assert_array_less(np.abs(got - mc_mean), 5 * mc_err + 2e-6)


# (origin, direction, base radius, t0, t1): a thin frustum, a thinner one, a wide near one.
FRUSTUMS = [
    ((0.1, -0.2, 0.3), (0.3, -0.2, -1.0), 0.01, 2.0, 2.1),
    ((0.1, -0.2, 0.3), (0.3, -0.2, -1.0), 0.003, 2.0, 2.02),
    ((0.0, 0.0, 0.0), (-1.2, 0.4, -0.9), 0.05, 0.5, 1.0),
]


@pytest.mark.parametrize("frustum", FRUSTUMS)
def test_matches_monte_carlo_over_the_conical_frustum(frustum):
  """The encoding of the frustum's Gaussian against the mean point encoding over the frustum.

  Tolerance: the Gaussian shares the frustum's mean and covariance, so for each coordinate
  X (spread s) and w = 2^k, Taylor's remainder |e^{iy} - 1 - iy + y^2/2| <= |y|^3/6 bounds
  |E e^{iwX} - E_Gauss e^{iwX}| <= w^3 (E|X - m|^3 + 2·sqrt(2/pi)·s^3)/6, rigorous, with the
  frustum's third absolute moment estimated from the samples: tight for low bands (w·s <= 0.1:
  below 5e-4) and vacuous for high ones. There both are near 0: the Gaussian's band is damped
  below exp(-18) for w·s >= 6; the frustum's density has jumps at its ends, so its
  characteristic function decays only like 1/(w·s) (a sinc for a uniform): below 0.05 there
  (measured <= 0.025). Monte Carlo noise: 5 standard errors.
  """
  origin, direction, radius, t0, t1 = frustum
  num_freqs = 12
  x = frustum_samples(np.random.default_rng(0), origin, direction, radius, t0, t1, 200_000)
  bands = point_encoding(x, num_freqs)  # [N, L, 6]
  mc, mc_err = bands.mean(0), 5 * bands.std(0) / np.sqrt(len(x))
  mean, var = cones.frustum_gaussians(np.float32(origin), np.float32(direction),
                                      np.float32(radius), np.float32([t0]), np.float32([t1]),
                                      diagonal=True)
  got = np.asarray(integrated_positional_encoding(mean[0], var[0], num_freqs))
  np.testing.assert_array_equal(got[:3], mean[0])  # the identity part: the mean
  got = got[3:].reshape(num_freqs, 6)
  s = np.sqrt(x.var(0))
  m3 = np.mean(np.abs(x - x.mean(0)) ** 3, axis=0)
  w = 2.0 ** np.arange(num_freqs)[:, None]
  taylor = np.tile(w ** 3 * (1.1 * m3 + 2 * np.sqrt(2 / np.pi) * s ** 3) / 6, (1, 2))  # [L, 6]
  np.testing.assert_array_less(np.abs(got - mc), np.minimum(taylor, 2.0) + mc_err + 1e-5)
  high = np.tile(w * np.sqrt(np.asarray(var[0], np.float64)) >= 6.0, (1, 2))
  assert high.any() and (~high).any()
  np.testing.assert_array_less(np.abs(got[high]), np.exp(-18.0))
  np.testing.assert_array_less(np.abs(mc[high]), 0.05)
  low = np.tile(w * s <= 0.1, (1, 2))
  assert low.any()
  np.testing.assert_array_less(np.abs(got - mc)[low], 5e-4 + mc_err[low])


def test_huge_variances_give_zero_features_and_finite_gradients():
  """Far samples and contracted space: var up to 1e30 and inf; the bands go to 0 exactly, the
  mean stays, and jax.grad w.r.t. mean and var is finite (debug_nans: no NaN anywhere)."""
  mean = jnp.float32([[0.3, -1.2, 2.0], [1e4, -3e5, 2e6], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
  var = jnp.float32([[1e10, 1e20, 1e30], [1e38, 3e38, np.inf], [1e6, 1e8, 1e12],
                     [1e-2, 1.0, 1e3]])
  num_freqs = 16
  features = integrated_positional_encoding(mean, var, num_freqs)
  assert np.all(np.isfinite(features))
  np.testing.assert_array_equal(features[:, :3], mean)
  np.testing.assert_array_equal(features[:3, 3:], 0.0)  # exp(-huge) underflows to exactly 0
  # var = 1e3: band 0 keeps exp(-500) = 0 too; var = 1e-2: band 0 keeps exp(-0.005).
  assert np.all(np.abs(features[3, 3:]) <= np.exp(-0.5 * 1e-2) + 1e-7)

  def loss(mean, var):
    return jnp.sum(integrated_positional_encoding(mean, var, num_freqs) ** 2)

  g_mean, g_var = jax.grad(loss, argnums=(0, 1))(mean, var)
  assert np.all(np.isfinite(g_mean)) and np.all(np.isfinite(g_var))
  np.testing.assert_array_equal(g_var[:3], 0.0)
  # A sweep of variances over 80 decades with every band, at several means.
  sweep = jnp.float32(10.0 ** np.linspace(-40, 38, 200))[:, None] * jnp.ones(3)
  means = jnp.float32([[0.1, 1.0, 10.0]]) * jnp.ones((200, 1))
  g_mean, g_var = jax.grad(loss, argnums=(0, 1))(means, sweep)
  assert np.all(np.isfinite(g_mean)) and np.all(np.isfinite(g_var))


def test_high_frequencies_stay_finite_and_damping_is_monotone():
  x = jnp.float32([[0.123, -0.77, 1.5], [1e3, -1e3, 0.5]])
  var = jnp.float32([[1e-12, 1e-9, 1e-6], [1e-10, 0.0, 1e-8]])
  features = integrated_positional_encoding(x, var, 16)
  assert features.shape == (2, 3 + 6 * 16) and np.all(np.isfinite(features))
  damping = band_damping(var, 16)  # [2, 16, 3]
  assert np.all(np.diff(damping, axis=-2) <= 0.0)  # finer bands are damped more
  np.testing.assert_allclose(damping, np.exp(-0.5 * (4.0 ** np.arange(16))[:, None]
                                             * np.asarray(var, np.float64)[:, None, :]),
                             rtol=1e-6, atol=1e-30)
