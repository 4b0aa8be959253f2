"""Tests of nerf_jax.fields.encodings.posenc against a float64 numpy loop in the reference's
feature order."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.fields.encodings import posenc

# Jitted once per shape: op-by-op dispatch compiles every primitive separately and is slow.
positional_encoding = jax.jit(posenc.positional_encoding, static_argnums=1)


def _reference_encoding(x, num_freqs):
  """The Keras reference's loop: [x, sin(2^0 x), cos(2^0 x), sin(2^1 x), ...], each a d-vector."""
  x = np.asarray(x, np.float64)
  features = [x]
  for k in range(num_freqs):
    features.append(np.sin(2.0 ** k * x))
    features.append(np.cos(2.0 ** k * x))
  return np.concatenate(features, axis=-1)


@pytest.mark.parametrize("num_freqs,dim", [(1, 3), (4, 3), (10, 3), (4, 2)])
def test_width_and_values_match_reference_order(num_freqs, dim):
  x = np.random.default_rng(0).uniform(-1.5, 1.5, (5, 7, dim)).astype(np.float32)
  out = positional_encoding(x, num_freqs)
  assert out.shape == (5, 7, dim + 2 * dim * num_freqs)
  assert out.shape[-1] == posenc.encoded_width(dim, num_freqs)
  assert out.dtype == jnp.float32
  # Same float32 input evaluated in float64: only sin/cos rounding differs.
  np.testing.assert_allclose(out, _reference_encoding(x, num_freqs), rtol=0, atol=3e-7)


def test_feature_layout_by_hand():
  """Band k holds [sin(2^k x), sin(2^k y), sin(2^k z), cos(2^k x), cos(2^k y), cos(2^k z)]."""
  x = np.array([0.1, 0.2, 0.3], np.float32)
  out = np.asarray(positional_encoding(x, 2), np.float64)
  xs = np.asarray(x, np.float64)
  np.testing.assert_allclose(out[:3], xs, atol=0)
  np.testing.assert_allclose(out[3:6], np.sin(xs), atol=1e-7)
  np.testing.assert_allclose(out[6:9], np.cos(xs), atol=1e-7)
  np.testing.assert_allclose(out[9:12], np.sin(2 * xs), atol=1e-7)
  np.testing.assert_allclose(out[12:15], np.cos(2 * xs), atol=1e-7)


def test_zero_bands_is_identity():
  x = np.arange(6, dtype=np.float32).reshape(2, 3)
  np.testing.assert_array_equal(posenc.positional_encoding(x, 0), x)
  assert posenc.encoded_width(3, 0) == 3


def test_gradient_matches_analytic():
  x = np.array([0.3, -0.7, 0.05], np.float32)
  num_freqs = 3
  grad = jax.jit(jax.grad(lambda v: jnp.sum(posenc.positional_encoding(v, num_freqs))))(x)
  xs = np.asarray(x, np.float64)
  expected = 1.0 + sum(2.0 ** k * (np.cos(2.0 ** k * xs) - np.sin(2.0 ** k * xs))
                       for k in range(num_freqs))
  np.testing.assert_allclose(grad, expected, rtol=1e-5, atol=1e-6)


def test_leading_dims_and_dtype():
  x = np.ones((2, 3, 4, 3), np.float32)
  assert positional_encoding(x, 5).shape == (2, 3, 4, 33)
  # The output keeps the input's dtype (pass float32: see the module docstring on accuracy).
  assert positional_encoding(x.astype(jnp.bfloat16), 2).dtype == jnp.bfloat16
