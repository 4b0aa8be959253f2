"""Tests of nerf_jax.sampling: stratified edges and inverse-CDF resampling."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax import sampling

# One batch of RAYS rays with S samples and N resamples for every test, and jitted entry points:
# few compilations keep the suite fast.
RAYS, S, N = 4, 16, 32
stratified = jax.jit(sampling.stratified, static_argnums=(2, 3, 5))
sample_pdf = jax.jit(sampling.sample_pdf, static_argnums=(2,))
NEAR = np.array([2.0, 0.5, 1.0, 2.0], np.float32)
FAR = np.array([6.0, 0.5 + 1e-6, 100.0, 6.0], np.float32)  # ray 1: a few ulps wide


def _strata(key=None, lindisp=False, near=NEAR, far=FAR):
  return np.asarray(stratified(near, far, S, (RAYS,), key, lindisp))


@pytest.mark.parametrize("lindisp", [False, True])
@pytest.mark.parametrize("use_key", [False, True])
def test_stratified_edges_sorted_and_pinned(lindisp, use_key):
  t = _strata(jax.random.PRNGKey(1) if use_key else None, lindisp)
  assert t.shape == (RAYS, S + 1) and t.dtype == np.float32
  assert np.all(np.diff(t, axis=-1) >= 0)
  np.testing.assert_array_equal(t[:, 0], NEAR)
  np.testing.assert_array_equal(t[:, -1], FAR)


def test_stratified_deterministic_is_evenly_spaced():
  t = _strata()
  for r in (0, 2, 3):
    np.testing.assert_allclose(t[r], np.linspace(NEAR[r], FAR[r], S + 1), rtol=1e-6)
  np.testing.assert_allclose(sampling.midpoints(t)[0], 2.125 + 0.25 * np.arange(S), rtol=1e-6)
  # Scalar bounds broadcast to the batch shape.
  np.testing.assert_array_equal(stratified(2.0, 6.0, S, (RAYS,), None, False), _strata(
      near=np.full(RAYS, 2.0, np.float32), far=np.full(RAYS, 6.0, np.float32)))


def test_stratified_jittered_midpoints_stay_in_their_strata():
  t = _strata(jax.random.PRNGKey(3)).astype(np.float64)
  mids = sampling.midpoints(t)[[0, 2, 3]]
  even = np.stack([np.linspace(NEAR[r], FAR[r], S + 1) for r in (0, 2, 3)])
  tol = 1e-5 * even[:, -1:]
  assert np.all(mids >= even[:, :-1] - tol) and np.all(mids <= even[:, 1:] + tol)
  # The jitter actually moves the samples, and fills each stratum.
  rel = (mids - even[:, :-1]) / (even[:, 1:] - even[:, :-1])
  assert rel.std() > 0.1 and rel.min() < 0.15 and rel.max() > 0.85


def test_stratified_keys():
  a, b = _strata(jax.random.PRNGKey(0)), _strata(jax.random.PRNGKey(0))
  c = _strata(jax.random.PRNGKey(1))
  np.testing.assert_array_equal(a, b)
  assert not np.allclose(a, c)


def test_stratified_lindisp_is_linear_in_disparity():
  t = _strata(lindisp=True).astype(np.float64)
  for r in (0, 2, 3):
    np.testing.assert_allclose(np.diff(1.0 / t[r]), (1.0 / FAR[r] - 1.0 / NEAR[r]) / S,
                               rtol=1e-4)


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


def _random_bins(seed):
  """Edges float32 [RAYS, S + 1] with uneven widths and sparse weights float32 [RAYS, S]."""
  rng = np.random.default_rng(seed)
  widths = rng.uniform(0.05, 0.5, (RAYS, S))
  t = (2.0 + np.concatenate([np.zeros((RAYS, 1)), np.cumsum(widths, -1)], -1)).astype(np.float32)
  weights = (rng.uniform(size=(RAYS, S)) ** 4 * (rng.uniform(size=(RAYS, S)) > 0.3))
  return t, weights.astype(np.float32)


@pytest.mark.parametrize("padding", [0.0, 0.01])
def test_sample_pdf_matches_brute_force_inverse_cdf(padding):
  t, weights = _random_bins(0)
  samples = np.asarray(sample_pdf(t, weights, N, None, padding))
  u = (np.arange(N) + 0.5) / N
  for r in range(RAYS):
    expected = _reference_inverse_cdf(t[r].astype(np.float64), weights[r], u, padding)
    np.testing.assert_allclose(samples[r], expected, rtol=0, atol=2e-5)


@pytest.mark.parametrize("use_key", [False, True])
def test_sample_pdf_sorted_and_in_range(use_key):
  t, weights = _random_bins(1)
  key = jax.random.PRNGKey(5) if use_key else None
  samples = np.asarray(sample_pdf(t, weights, N, key, 0.01))
  assert samples.shape == (RAYS, N) and samples.dtype == np.float32
  assert np.all(np.diff(samples, axis=-1) >= 0)
  assert np.all(samples >= t[:, :1]) and np.all(samples <= t[:, -1:])


@pytest.mark.parametrize("use_key", [False, True])
def test_sample_pdf_one_hot_weights_stay_in_the_bin(use_key):
  t, _ = _random_bins(2)
  bins = np.array([0, 5, 10, S - 1])
  weights = np.eye(S, dtype=np.float32)[bins]
  key = jax.random.PRNGKey(7) if use_key else None
  samples = np.asarray(sample_pdf(t, weights, N, key, 0.0))
  lo, hi = t[np.arange(RAYS), bins], t[np.arange(RAYS), bins + 1]
  assert np.all(samples >= lo[:, None]) and np.all(samples <= hi[:, None])


def test_sample_pdf_determinism():
  t, weights = _random_bins(3)
  np.testing.assert_array_equal(sample_pdf(t, weights, N, None, 0.01),
                                sample_pdf(t, weights, N, None, 0.01))
  k = jax.random.PRNGKey(2)
  a, b = sample_pdf(t, weights, N, k, 0.01), sample_pdf(t, weights, N, k, 0.01)
  np.testing.assert_array_equal(a, b)
  assert not np.allclose(a, sample_pdf(t, weights, N, jax.random.PRNGKey(3), 0.01))


def _sum_of_samples(t, weights):
  return jnp.sum(sampling.sample_pdf(t, weights, N))


def test_sample_pdf_gradients_stopped():
  t, weights = _random_bins(4)
  g_t, g_w = jax.jit(jax.grad(_sum_of_samples, argnums=(0, 1)))(t, weights)
  np.testing.assert_array_equal(g_t, 0.0)
  np.testing.assert_array_equal(g_w, 0.0)


def test_merge_edges_and_midpoints():
  t = np.array([0.0, 1.0, 2.0, 4.0], np.float32)
  merged = sampling.merge_edges(t, np.array([3.0, 0.5], np.float32))
  np.testing.assert_array_equal(merged, [0.0, 0.5, 1.0, 2.0, 3.0, 4.0])
  np.testing.assert_array_equal(sampling.midpoints(t), [0.5, 1.5, 3.0])


@pytest.mark.parametrize("batch", [(), (3,), (2, 4)])
def test_sample_pdf_with_a_single_interval_is_uniform_in_it(batch):
  # One coarse interval [t0, t1]: the pdf is uniform there, so quantile u lands at t0 + u·(t1 - t0).
  t0 = jnp.broadcast_to(jnp.linspace(1.0, 2.0, max(1, int(np.prod(batch)))).reshape(batch), batch)
  t = jnp.stack([t0, t0 + 4.0], axis=-1)
  weights = jnp.full((*batch, 1), 0.3)
  got = sampling.sample_pdf(t, weights, 5)
  u = (np.arange(5) + 0.5) / 5
  np.testing.assert_allclose(got, np.asarray(t0)[..., None] + 4.0 * u, rtol=1e-6)
  jittered = np.asarray(sampling.sample_pdf(t, weights, 5, jax.random.PRNGKey(0)))
  assert jittered.shape == (*batch, 5)
  start = np.asarray(t0)[..., None]
  assert np.all(jittered >= start) and np.all(jittered <= start + 4.0)
