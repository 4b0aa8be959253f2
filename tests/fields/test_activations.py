"""Density activations and the learning-rate schedule: values against closed forms."""

import jax
import numpy as np
import pytest

from nerf_jax.fields import activations

RAW = np.array([-30.0, -3.0, -1.0, 0.0, 0.5, 1.0, 4.0, 30.0, 87.0, 88.0, 89.0, 200.0])


def test_relu_values():
  np.testing.assert_array_equal(activations.relu(RAW), np.maximum(RAW, 0.0).astype(np.float32))


def test_softplus_is_shifted_by_minus_one():
  expected = np.log1p(np.exp(RAW.astype(np.float64) - 1.0))
  np.testing.assert_allclose(activations.shifted_softplus(RAW), expected, rtol=1e-6)
  assert float(activations.shifted_softplus(1.0)) == pytest.approx(np.log(2.0), rel=1e-6)


def test_exp_is_clamped_at_88_with_zero_gradient_above():
  expected = np.exp(np.minimum(RAW.astype(np.float64), 88.0))
  np.testing.assert_allclose(activations.safe_exp(RAW), expected, rtol=1e-6)
  grad = jax.vmap(jax.grad(lambda x: activations.safe_exp(x)))(RAW.astype(np.float32))
  np.testing.assert_allclose(grad[RAW < 88], expected[RAW < 88], rtol=1e-6)
  np.testing.assert_array_equal(grad[RAW > 88], 0.0)
  assert np.all(np.isfinite(activations.safe_exp(RAW)))
