"""The volume rendering quadrature (nerf_jax/volume/quadrature.py) against a loop over the
intervals, and its two derivatives of alpha."""

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.volume import quadrature


def _loop_weights(sigma, t):
  """w_i = (1 - exp(-tau_i))·exp(-sum_{j<i} tau_j), one ray at a time, in float64."""
  out = np.zeros(sigma.shape)
  for ray in range(sigma.shape[0]):
    before = 0.0
    for i in range(sigma.shape[1]):
      tau = float(sigma[ray, i]) * max(float(t[ray, i + 1] - t[ray, i]), 0.0)
      out[ray, i] = (1.0 - np.exp(-tau)) * np.exp(-before)
      before += tau
  return out


def test_weights_and_the_transmittance_left_match_a_loop():
  rng = np.random.default_rng(0)
  sigma = rng.uniform(0.0, 3.0, (4, 7)).astype(np.float32)
  t = np.sort(rng.uniform(1.0, 3.0, (4, 8)), axis=-1).astype(np.float32)
  weights, left = quadrature.compute_weights(sigma, t)
  expected = _loop_weights(sigma, t)
  np.testing.assert_allclose(weights, expected, rtol=1e-5, atol=1e-7)
  np.testing.assert_allclose(left, 1.0 - expected.sum(-1), rtol=1e-5, atol=1e-6)
  np.testing.assert_array_equal(quadrature.weights(sigma, t), weights)


def test_an_infinite_density_is_clamped_and_opaque():
  t = np.array([[0.0, 1.0, 2.0, 3.0]], np.float32)
  weights, left = quadrature.compute_weights(np.array([[0.0, np.inf, 1.0]], np.float32), t)
  np.testing.assert_array_equal(weights, [[0.0, 1.0, 0.0]])
  assert float(left[0]) == 0.0


def test_both_derivatives_of_alpha_agree_to_rounding_and_give_the_same_values():
  rng = np.random.default_rng(1)
  sigma = jnp.asarray(rng.uniform(0.0, 2.0, (3, 5)), jnp.float32)
  t = jnp.asarray(np.sort(rng.uniform(0.0, 2.0, (3, 6)), axis=-1), jnp.float32)
  exact = lambda s: jnp.sum(quadrature.weights(s, t) ** 2)
  plain = lambda s: jnp.sum(quadrature.weights(s, t, exact_derivative=False) ** 2)
  np.testing.assert_array_equal(quadrature.weights(sigma, t),
                                quadrature.weights(sigma, t, exact_derivative=False))
  np.testing.assert_allclose(jax.grad(exact)(sigma), jax.grad(plain)(sigma), rtol=1e-5,
                             atol=1e-7)
