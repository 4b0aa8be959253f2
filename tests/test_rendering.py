"""Tests of nerf_jax.rendering.composite against a brute-force loop and analytic gradients."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax import rendering


def _reference_composite(rgb, sigma, t, background=None):
  """Python loop in float64: T_i = prod_{j<i} exp(-sigma_j delta_j), w_i = T_i (1 - e^-tau_i)."""
  rgb, sigma, t = (np.asarray(a, np.float64) for a in (rgb, sigma, t))
  weights = np.zeros_like(sigma)
  transmittance = 1.0
  for i in range(len(sigma)):
    tau = sigma[i] * (t[i + 1] - t[i])
    weights[i] = transmittance * -math.expm1(-tau)
    transmittance *= math.exp(-tau)
  acc = weights.sum()
  colour = weights @ rgb
  if background is not None:
    colour = colour + transmittance * np.asarray(background, np.float64)
  mids = 0.5 * (t[1:] + t[:-1])
  depth = (weights @ mids) / acc if acc > 0 else t[-1]
  return {"rgb": colour, "acc": acc, "weights": weights, "depth": depth}


def _random_ray(key, num_samples=24, scale=1.0):
  k1, k2, k3 = jax.random.split(key, 3)
  t = 2.0 + jnp.concatenate([jnp.zeros(1), jnp.cumsum(
      jax.random.uniform(k1, (num_samples,), minval=0.02, maxval=0.3))])
  sigma = scale * jnp.exp(jax.random.normal(k2, (num_samples,)))
  rgb = jax.random.uniform(k3, (num_samples, 3))
  return rgb, sigma, t


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("scale", [0.1, 1.0, 10.0])
@pytest.mark.parametrize("background", [None, (0.2, 0.5, 1.0)])
def test_composite_matches_loop(seed, scale, background):
  rgb, sigma, t = _random_ray(jax.random.PRNGKey(seed), scale=scale)
  out = rendering.composite(rgb, sigma, t, None if background is None else jnp.array(background))
  ref = _reference_composite(rgb, sigma, t, background)
  for name in ("rgb", "acc", "weights"):
    np.testing.assert_allclose(out[name], ref[name], rtol=1e-5, atol=1e-6, err_msg=name)
  np.testing.assert_allclose(out["depth"], ref["depth"], rtol=1e-5)
  assert all(out[k].dtype == jnp.float32 for k in out)


def test_composite_batched_matches_per_ray():
  keys = jax.random.split(jax.random.PRNGKey(9), 6)
  rgb, sigma, t = jax.vmap(_random_ray)(keys)
  out = rendering.composite(rgb.reshape(2, 3, 24, 3), sigma.reshape(2, 3, 24), t.reshape(2, 3, 25))
  for r in range(6):
    single = rendering.composite(rgb[r], sigma[r], t[r])
    for name in ("rgb", "acc", "depth", "weights"):
      np.testing.assert_allclose(out[name].reshape(6, *single[name].shape)[r], single[name],
                                 rtol=1e-6, atol=1e-7)


def test_gradient_wrt_colour_is_weight():
  rgb, sigma, t = _random_ray(jax.random.PRNGKey(3))
  jac = jax.jacobian(lambda c: rendering.composite(c, sigma, t)["rgb"])(rgb)  # [3, S, 3]
  weights = rendering.composite(rgb, sigma, t)["weights"]
  for ch in range(3):
    np.testing.assert_allclose(jac[ch, :, ch], weights, rtol=1e-6, atol=1e-7)
    other = [c for c in range(3) if c != ch]
    np.testing.assert_array_equal(jac[ch][:, other], 0.0)


def test_gradient_wrt_density_matches_analytic():
  """d rgb / d sigma_i = delta_i·(T_{i+1} c_i - sum_{j>i} w_j c_j - T_S·bg), from the loop."""
  rgb, sigma, t = _random_ray(jax.random.PRNGKey(4), num_samples=12)
  bg = jnp.array([0.3, 0.6, 0.9])
  jac = jax.jacobian(lambda s: rendering.composite(rgb, s, t, bg)["rgb"])(sigma)  # [3, S]
  ref = _reference_composite(rgb, sigma, t, bg)
  w, c = ref["weights"], np.asarray(rgb, np.float64)
  delta = np.diff(np.asarray(t, np.float64))
  tau = np.asarray(sigma, np.float64) * delta
  trans_after = np.exp(-np.cumsum(tau))  # T_{i+1}
  expected = np.stack([delta[i] * (trans_after[i] * c[i] - w[i + 1:] @ c[i + 1:]
                                   - trans_after[-1] * np.asarray(bg, np.float64))
                       for i in range(len(delta))], axis=-1)
  np.testing.assert_allclose(jac, expected, rtol=1e-4, atol=1e-6)


def test_opaque_sample_acc_gradient():
  """One sample of density sigma over delta: acc = 1 - e^{-sigma delta}, d acc/d sigma = delta e^{-sigma delta}."""
  t = jnp.array([1.0, 1.5])
  rgb = jnp.ones((1, 3))
  for sigma in [0.1, 4.0, 30.0]:
    grad = jax.grad(lambda s: rendering.composite(rgb, s, t)["acc"])(jnp.array([sigma]))
    np.testing.assert_allclose(grad[0], 0.5 * math.exp(-0.5 * sigma), rtol=1e-6)


def test_opacity_and_depth_range():
  keys = jax.random.split(jax.random.PRNGKey(5), 32)
  rgb, sigma, t = jax.vmap(lambda k: _random_ray(k, scale=3.0))(keys)
  out = rendering.composite(rgb, sigma, t)
  assert np.all(out["acc"] >= 0) and np.all(out["acc"] <= 1)
  assert np.all(out["weights"] >= 0)
  assert np.all(out["depth"] >= t[:, 0]) and np.all(out["depth"] <= t[:, -1])
  np.testing.assert_allclose(jnp.sum(out["weights"], -1), out["acc"], atol=1e-6)


def test_depth_of_an_opaque_sample_is_its_distance():
  t = jnp.linspace(2.0, 6.0, 33)
  sigma = jnp.zeros(32).at[20].set(1e4)  # one thin opaque slab in [t_20, t_21]
  rgb = jnp.zeros((32, 3)).at[20].set(jnp.array([1.0, 0.0, 0.5]))
  out = rendering.composite(rgb, sigma, t, jnp.ones(3))
  surface = 0.5 * (t[20] + t[21])
  np.testing.assert_allclose(out["depth"], surface, rtol=1e-6)
  np.testing.assert_allclose(out["acc"], 1.0, atol=1e-7)
  np.testing.assert_allclose(out["rgb"], [1.0, 0.0, 0.5], atol=1e-6)  # background hidden
  np.testing.assert_array_equal(out["weights"][21:], 0.0)


def test_background_fills_the_remaining_transmittance():
  rgb, sigma, t = _random_ray(jax.random.PRNGKey(6), scale=0.3)
  bg = jnp.array([0.1, 0.7, 0.4])
  black = rendering.composite(rgb, sigma, t)
  over = rendering.composite(rgb, sigma, t, bg)
  np.testing.assert_allclose(over["rgb"], black["rgb"] + (1 - black["acc"]) * bg, atol=1e-6)
  # A scalar background broadcasts like a grey colour.
  grey = rendering.composite(rgb, sigma, t, 1.0)
  np.testing.assert_allclose(grey["rgb"], black["rgb"] + (1 - black["acc"]), atol=1e-6)
  # An empty ray shows exactly the background.
  empty = rendering.composite(rgb, jnp.zeros_like(sigma), t, bg)
  np.testing.assert_array_equal(empty["rgb"], bg)


def test_disparity():
  np.testing.assert_allclose(rendering.disparity(jnp.array([2.0, 0.5])), [0.5, 2.0])
  assert np.isfinite(rendering.disparity(jnp.array(0.0)))
