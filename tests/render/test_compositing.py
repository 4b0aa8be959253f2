"""Tests of nerf_jax.rendering.composite against a brute-force loop and analytic gradients."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax import rendering

# One ray length S for every test, and jitted entry points: few compilations keep the suite fast.
S = 24
composite = jax.jit(rendering.composite)


def _colour_and_acc(rgb, sigma, t, background):
  out = rendering.composite(rgb, sigma, t, background)
  return out["rgb"], out["acc"]


# Jacobians of (rgb [3], acc []) with respect to (rgb [S, 3], sigma [S]) of one ray.
jacobians = jax.jit(jax.jacobian(_colour_and_acc, argnums=(0, 1)))


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
  return {"rgb": colour, "acc": acc, "weights": weights, "depth": depth,
          "transmittance_end": transmittance}


def _random_rays(seed, num_rays=1, scale=1.0):
  """rgb float32 [R, S, 3], sigma float32 [R, S] (log-normal), t float32 [R, S + 1] from 2."""
  rng = np.random.default_rng(seed)
  widths = rng.uniform(0.02, 0.3, (num_rays, S))
  t = 2.0 + np.concatenate([np.zeros((num_rays, 1)), np.cumsum(widths, -1)], -1)
  sigma = scale * np.exp(rng.normal(size=(num_rays, S)))
  rgb = rng.uniform(size=(num_rays, S, 3))
  return rgb.astype(np.float32), sigma.astype(np.float32), t.astype(np.float32)


BACKGROUND = np.array([0.2, 0.5, 1.0], np.float32)


@pytest.mark.parametrize("background", [None, BACKGROUND])
def test_composite_matches_loop(background):
  rays_ = []
  for seed, scale in enumerate([0.1, 1.0, 10.0, 0.01, 3.0, 30.0]):
    rays_.append(_random_rays(seed, 1, scale))
  rgb, sigma, t = (np.concatenate(a) for a in zip(*rays_))
  out = composite(rgb, sigma, t, background)
  assert all(v.dtype == jnp.float32 for v in out.values())
  for r in range(len(t)):
    ref = _reference_composite(rgb[r], sigma[r], t[r], background)
    for name in ("rgb", "acc", "weights"):
      np.testing.assert_allclose(out[name][r], ref[name], rtol=1e-5, atol=1e-6, err_msg=name)
    np.testing.assert_allclose(out["depth"][r], ref["depth"], rtol=1e-5)


def test_composite_batched_matches_per_ray():
  rgb, sigma, t = _random_rays(9, num_rays=6)
  out = composite(rgb.reshape(2, 3, S, 3), sigma.reshape(2, 3, S), t.reshape(2, 3, S + 1), None)
  flat = {k: np.asarray(v).reshape(6, *v.shape[2:]) for k, v in out.items()}
  for r in range(6):
    single = composite(rgb[r:r + 1], sigma[r:r + 1], t[r:r + 1], None)
    for name in ("rgb", "acc", "depth", "weights"):
      np.testing.assert_allclose(flat[name][r], single[name][0], rtol=1e-6, atol=1e-7)


def test_gradient_wrt_colour_is_weight():
  rgb, sigma, t = (a[0] for a in _random_rays(3))
  (jac_rgb, _), _ = jacobians(rgb, sigma, t, BACKGROUND)  # [3, S, 3]
  weights = _reference_composite(rgb, sigma, t)["weights"]
  for ch in range(3):
    np.testing.assert_allclose(jac_rgb[ch, :, ch], weights, rtol=1e-5, atol=1e-7)
    other = [c for c in range(3) if c != ch]
    np.testing.assert_array_equal(jac_rgb[ch][:, other], 0.0)


def test_gradient_wrt_density_matches_analytic():
  """d rgb / d sigma_i = delta_i·(T_{i+1} c_i - sum_{j>i} w_j c_j - T_S·bg), from the loop;
  d acc / d sigma_i = delta_i·T_S."""
  rgb, sigma, t = (a[0] for a in _random_rays(4, scale=0.3))
  (_, jac_sigma), (_, grad_acc) = jacobians(rgb, sigma, t, BACKGROUND)
  ref = _reference_composite(rgb, sigma, t, BACKGROUND)
  w, c = ref["weights"], rgb.astype(np.float64)
  delta = np.diff(t.astype(np.float64))
  trans_after = np.exp(-np.cumsum(sigma * delta))  # T_{i+1}
  expected = np.stack([delta[i] * (trans_after[i] * c[i] - w[i + 1:] @ c[i + 1:]
                                   - trans_after[-1] * BACKGROUND) for i in range(S)], axis=-1)
  np.testing.assert_allclose(jac_sigma, expected, rtol=1e-4, atol=1e-6)
  np.testing.assert_allclose(grad_acc, delta * ref["transmittance_end"], rtol=1e-5)


@pytest.mark.parametrize("sigma_value", [0.1, 4.0, 30.0])
def test_single_sample_acc_gradient(sigma_value):
  """One non-empty sample: acc = 1 - e^(-sigma delta), d acc / d sigma = delta e^(-sigma delta)."""
  rgb, _, t = (a[0] for a in _random_rays(5))
  sigma = np.zeros(S, np.float32)
  sigma[7] = sigma_value
  delta = float(t[8]) - float(t[7])
  _, (_, grad_acc) = jacobians(rgb, sigma, t, BACKGROUND)
  np.testing.assert_allclose(grad_acc[7], delta * math.exp(-sigma_value * delta), rtol=1e-5)
  np.testing.assert_allclose(composite(rgb, sigma, t, None)["acc"],
                             -math.expm1(-sigma_value * delta), rtol=1e-6)


def test_opacity_and_depth_range():
  rgb, sigma, t = _random_rays(5, num_rays=6, scale=3.0)
  out = {k: np.asarray(v) for k, v in composite(rgb, sigma, t, None).items()}
  assert np.all(out["acc"] >= 0) and np.all(out["acc"] <= 1)
  assert np.all(out["weights"] >= 0)
  assert np.all(out["depth"] >= t[:, 0]) and np.all(out["depth"] <= t[:, -1])
  np.testing.assert_allclose(np.sum(out["weights"], -1), out["acc"], atol=1e-6)


def test_depth_of_an_opaque_sample_is_its_distance():
  t = np.linspace(2.0, 6.0, S + 1).astype(np.float32)
  sigma = np.zeros(S, np.float32)
  sigma[20] = 1e4  # one thin opaque slab in [t_20, t_21]
  rgb = np.zeros((S, 3), np.float32)
  rgb[20] = [1.0, 0.0, 0.5]
  out = composite(rgb, sigma, t, np.ones(3, np.float32))
  np.testing.assert_allclose(out["depth"], 0.5 * (t[20] + t[21]), rtol=1e-6)
  np.testing.assert_allclose(out["acc"], 1.0, atol=1e-7)
  np.testing.assert_allclose(out["rgb"], [1.0, 0.0, 0.5], atol=1e-6)  # background hidden
  np.testing.assert_array_equal(out["weights"][21:], 0.0)


def test_background_fills_the_remaining_transmittance():
  rgb, sigma, t = _random_rays(6, num_rays=6, scale=0.3)
  black = composite(rgb, sigma, t, None)
  over = composite(rgb, sigma, t, BACKGROUND)
  expected = np.asarray(black["rgb"]) + (1 - np.asarray(black["acc"]))[:, None] * BACKGROUND
  np.testing.assert_allclose(over["rgb"], expected, atol=1e-6)
  # A scalar background broadcasts like a grey colour.
  grey = composite(rgb, sigma, t, np.float32(1.0))
  np.testing.assert_allclose(grey["rgb"], black["rgb"] + (1 - black["acc"])[:, None], atol=1e-6)
  # An empty ray shows exactly the background.
  empty = composite(rgb, np.zeros_like(sigma), t, BACKGROUND)
  np.testing.assert_array_equal(empty["rgb"], np.broadcast_to(BACKGROUND, (6, 3)))


def test_disparity():
  np.testing.assert_allclose(rendering.disparity(np.array([2.0, 0.5], np.float32)), [0.5, 2.0])
  assert np.isfinite(rendering.disparity(np.float32(0.0)))
