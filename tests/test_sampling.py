"""Tests of nerf_jax.sampling: stratified edges and inverse-CDF resampling."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax import sampling


@pytest.mark.parametrize("lindisp", [False, True])
@pytest.mark.parametrize("use_key", [False, True])
def test_stratified_edges_sorted_and_pinned(lindisp, use_key):
  key = jax.random.PRNGKey(1) if use_key else None
  near = jnp.array([2.0, 0.5, 1.0], jnp.float32)
  far = jnp.array([6.0, 0.5 + 1e-6, 100.0], jnp.float32)
  t = sampling.stratified(near, far, 16, (3,), key, lindisp)
  assert t.shape == (3, 17) and t.dtype == jnp.float32
  assert np.all(np.diff(t, axis=-1) >= 0)
  np.testing.assert_array_equal(t[:, 0], near)
  np.testing.assert_array_equal(t[:, -1], far)


def test_stratified_deterministic_is_evenly_spaced():
  t = sampling.stratified(2.0, 6.0, 8, (4, 2))
  assert t.shape == (4, 2, 9)
  np.testing.assert_allclose(t, np.broadcast_to(np.linspace(2.0, 6.0, 9), (4, 2, 9)), atol=1e-6)
  np.testing.assert_allclose(sampling.midpoints(t)[0, 0], 2.25 + 0.5 * np.arange(8), atol=1e-6)


def test_stratified_jittered_midpoints_stay_in_their_strata():
  near, far, num = 2.0, 6.0, 32
  t = sampling.stratified(near, far, num, (64,), jax.random.PRNGKey(3))
  mids = np.asarray(sampling.midpoints(t), np.float64)
  strata = np.linspace(near, far, num + 1)
  eps = 1e-5
  assert np.all(mids >= strata[:-1] - eps) and np.all(mids <= strata[1:] + eps)
  # The jitter actually moves the samples, and fills each stratum.
  rel = (mids - strata[:-1]) / (strata[1] - strata[0])
  assert rel.std() > 0.1 and rel.min() < 0.1 and rel.max() > 0.9


def test_stratified_keys():
  a = sampling.stratified(2.0, 6.0, 8, (5,), jax.random.PRNGKey(0))
  b = sampling.stratified(2.0, 6.0, 8, (5,), jax.random.PRNGKey(0))
  c = sampling.stratified(2.0, 6.0, 8, (5,), jax.random.PRNGKey(1))
  np.testing.assert_array_equal(a, b)
  assert not np.allclose(a, c)


def test_stratified_lindisp_is_linear_in_disparity():
  near, far, num = 1.0, 10.0, 9
  t = np.asarray(sampling.stratified(near, far, num, (), lindisp=True), np.float64)
  np.testing.assert_allclose(np.diff(1.0 / t), (1.0 / far - 1.0 / near) / num, rtol=1e-5)


def _reference_inverse_cdf(t, weights, u, padding):
  """Brute force, float64: find the bin of each u by a linear scan, interpolate inside it."""
  w = np.maximum(np.asarray(weights, np.float64), 0) + padding
  w = np.where(np.diff(t) > 0, w, 0.0)
  cdf = np.concatenate([[0.0], np.cumsum(w) / w.sum()])
  out = []
  for v in u:
    k = max(i for i in range(len(w)) if cdf[i] <= v and cdf[i + 1] > cdf[i])
    frac = (v - cdf[k]) / (cdf[k + 1] - cdf[k])
    out.append(t[k] + frac * (t[k + 1] - t[k]))
  return np.array(out)


@pytest.mark.parametrize("padding", [0.0, 0.01])
def test_sample_pdf_matches_brute_force_inverse_cdf(padding):
  rng = np.random.default_rng(0)
  t = np.concatenate([[2.0], 2.0 + np.cumsum(rng.uniform(0.05, 0.5, 12))]).astype(np.float32)
  weights = rng.uniform(0, 1, 12).astype(np.float32) * (rng.uniform(size=12) > 0.3)
  num = 40
  samples = sampling.sample_pdf(jnp.asarray(t), jnp.asarray(weights), num, None, padding)
  u = (np.arange(num) + 0.5) / num
  expected = _reference_inverse_cdf(t.astype(np.float64), weights, u, padding)
  np.testing.assert_allclose(samples, expected, rtol=0, atol=2e-5)


@pytest.mark.parametrize("use_key", [False, True])
def test_sample_pdf_sorted_and_in_range(use_key):
  key = jax.random.PRNGKey(5) if use_key else None
  kt, kw = jax.random.split(jax.random.PRNGKey(4))
  t = sampling.stratified(2.0, 6.0, 16, (8,), kt)
  weights = jax.random.uniform(kw, (8, 16)) ** 4
  samples = sampling.sample_pdf(t, weights, 32, key)
  assert samples.shape == (8, 32) and samples.dtype == jnp.float32
  assert np.all(np.diff(samples, axis=-1) >= 0)
  assert np.all(samples >= t[:, :1]) and np.all(samples <= t[:, -1:])


@pytest.mark.parametrize("use_key", [False, True])
def test_sample_pdf_one_hot_weights_stay_in_the_bin(use_key):
  key = jax.random.PRNGKey(7) if use_key else None
  t = sampling.stratified(2.0, 6.0, 16, (16,))
  weights = jax.nn.one_hot(jnp.arange(16), 16)  # ray r weights bin r
  samples = sampling.sample_pdf(t, weights, 64, key, padding=0.0)
  lo = jnp.take_along_axis(t, jnp.arange(16)[:, None], axis=-1)
  hi = jnp.take_along_axis(t, jnp.arange(16)[:, None] + 1, axis=-1)
  assert np.all(samples >= lo) and np.all(samples <= hi)


def test_sample_pdf_determinism():
  t = sampling.stratified(2.0, 6.0, 8, (3,))
  weights = jax.random.uniform(jax.random.PRNGKey(0), (3, 8))
  np.testing.assert_array_equal(sampling.sample_pdf(t, weights, 16, None),
                                sampling.sample_pdf(t, weights, 16, None))
  k = jax.random.PRNGKey(2)
  np.testing.assert_array_equal(sampling.sample_pdf(t, weights, 16, k),
                                sampling.sample_pdf(t, weights, 16, k))
  assert not np.allclose(sampling.sample_pdf(t, weights, 16, k),
                         sampling.sample_pdf(t, weights, 16, jax.random.PRNGKey(3)))


def test_sample_pdf_gradients_stopped():
  t = sampling.stratified(2.0, 6.0, 8, ())
  weights = jax.random.uniform(jax.random.PRNGKey(0), (8,))
  g_t, g_w = jax.grad(lambda a, b: jnp.sum(sampling.sample_pdf(a, b, 16)), argnums=(0, 1))(
      t, weights)
  np.testing.assert_array_equal(g_t, 0.0)
  np.testing.assert_array_equal(g_w, 0.0)


def test_merge_edges_and_midpoints():
  t = jnp.array([0.0, 1.0, 2.0, 4.0])
  merged = sampling.merge_edges(t, jnp.array([3.0, 0.5]))
  np.testing.assert_array_equal(merged, [0.0, 0.5, 1.0, 2.0, 3.0, 4.0])
  np.testing.assert_array_equal(sampling.midpoints(t), [0.5, 1.5, 3.0])
