"""Tests of nerf_jax.samplers.spacing: stratified edges and inverse-CDF resampling."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.samplers import spacing

# One batch of RAYS rays with S samples and N resamples for every test, and jitted entry points:
# few compilations keep the suite fast.
RAYS, S, N = 4, 16, 32
stratified = jax.jit(spacing.stratified, static_argnums=(2, 3, 5))
sample_pdf = jax.jit(spacing.sample_pdf, static_argnums=(2,))
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
  np.testing.assert_allclose(spacing.midpoints(t)[0], 2.125 + 0.25 * np.arange(S), rtol=1e-6)
  # Scalar bounds broadcast to the batch shape.
  np.testing.assert_array_equal(stratified(2.0, 6.0, S, (RAYS,), None, False), _strata(
      near=np.full(RAYS, 2.0, np.float32), far=np.full(RAYS, 6.0, np.float32)))


def test_stratified_jittered_midpoints_stay_in_their_strata():
  t = _strata(jax.random.PRNGKey(3)).astype(np.float64)
  mids = spacing.midpoints(t)[[0, 2, 3]]
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
  return jnp.sum(spacing.sample_pdf(t, weights, N))


def test_sample_pdf_gradients_stopped():
  t, weights = _random_bins(4)
  g_t, g_w = jax.jit(jax.grad(_sum_of_samples, argnums=(0, 1)))(t, weights)
  np.testing.assert_array_equal(g_t, 0.0)
  np.testing.assert_array_equal(g_w, 0.0)


def test_merge_edges_and_midpoints():
  t = np.array([0.0, 1.0, 2.0, 4.0], np.float32)
  merged = spacing.merge_edges(t, np.array([3.0, 0.5], np.float32))
  np.testing.assert_array_equal(merged, [0.0, 0.5, 1.0, 2.0, 3.0, 4.0])
  np.testing.assert_array_equal(spacing.midpoints(t), [0.5, 1.5, 3.0])


@pytest.mark.parametrize("batch", [(), (3,), (2, 4)])
def test_sample_pdf_with_a_single_interval_is_uniform_in_it(batch):
  # One coarse interval [t0, t1]: the pdf is uniform there, so quantile u lands at
  # t0 + u·(t1 - t0).
  t0 = jnp.broadcast_to(jnp.linspace(1.0, 2.0, max(1, int(np.prod(batch)))).reshape(batch), batch)
  t = jnp.stack([t0, t0 + 4.0], axis=-1)
  weights = jnp.full((*batch, 1), 0.3)
  got = spacing.sample_pdf(t, weights, 5)
  u = (np.arange(5) + 0.5) / 5
  np.testing.assert_allclose(got, np.asarray(t0)[..., None] + 4.0 * u, rtol=1e-6)
  jittered = np.asarray(spacing.sample_pdf(t, weights, 5, jax.random.PRNGKey(0)))
  assert jittered.shape == (*batch, 5)
  start = np.asarray(t0)[..., None]
  assert np.all(jittered >= start) and np.all(jittered <= start + 4.0)


# --- stratified_unbounded -----------------------------------------------------------------------

stratified_unbounded = jax.jit(spacing.stratified_unbounded, static_argnums=(3, 4))
# Rays: in then out of the inner region; starting outside it (t_inner < near); leaving it exactly
# at near; never leaving it before far; near = 0 with a miss (t_inner = 0); far = inf; near = far.
U_NEAR = np.array([0.5, 2.0, 1.0, 0.5, 0.0, 0.2, 3.0], np.float32)
U_INNER = np.array([2.5, 1.0, 1.0, 8.0, 0.0, 1.7, 3.0], np.float32)
U_FAR = np.array([1e10, np.inf, 1e4, 6.0, np.inf, 50.0, 3.0], np.float32)
U_RAYS = len(U_NEAR)


def _unbounded(key=None, fraction=0.5, near=U_NEAR, t_inner=U_INNER, far=U_FAR):
  return np.asarray(stratified_unbounded(near, t_inner, far, S, (len(near),), key, fraction))


def _reference_strata(key):
  """The stratified positions s in float64 [U_RAYS, S + 1] (`stratified`'s strata and jitter)."""
  s = np.broadcast_to(np.linspace(0.0, 1.0, S + 1), (U_RAYS, S + 1))
  if key is None:
    return s
  mids = 0.5 * (s[:, 1:] + s[:, :-1])
  lower = np.concatenate([s[:, :1], mids], -1)
  upper = np.concatenate([mids, s[:, -1:]], -1)
  return lower + (upper - lower) * np.asarray(jax.random.uniform(key, s.shape), np.float64)


def _ray_split(near, t_inner, far, fraction):
  """(far, t_inner, f) of one ray as documented: far capped at 1e10, t_inner clamped into
  [near, far], the inner share f = 0 for a ray starting outside, 1 for one never leaving."""
  far = min(float(far), float(np.float32(1e10)))
  t_in = min(max(float(t_inner), float(near)), far)
  f = 0.0 if t_in <= near else 1.0 if t_in >= far else fraction
  return far, t_in, f


def _reference_unbounded(near, t_inner, far, s, fraction):
  """Brute force, float64, one edge at a time: linear in t on s <= f, linear in 1/t beyond."""
  far, t_in, f = _ray_split(near, t_inner, far, fraction)
  start = max(t_in, 1e-3)  # the documented clamp: 1/0 = inf
  edges = []
  for x in s:
    if x <= f:
      edges.append(near + (t_in - near) * (x / f if f > 0 else 0.0))
    else:
      v = (x - f) / (1.0 - f)
      edges.append(min(max(1.0 / (1.0 / start + (1.0 / far - 1.0 / start) * v), t_in), far))
  edges[0], edges[-1] = near, far
  return np.array(edges)


def _to_s(near, t_inner, far, t, fraction):
  """The inverse map t -> s of one ray (float64): where in [0, 1] each edge sits."""
  far, t_in, f = _ray_split(near, t_inner, far, fraction)
  start = max(t_in, 1e-3)
  t = np.asarray(t, np.float64)
  linear = f * (t - near) / (t_in - near) if t_in > near else np.zeros_like(t)
  span = 1.0 / start - 1.0 / far  # 0 where the ray never leaves the region (f = 1: no beyond)
  beyond = f + (1.0 - f) * (1.0 / start - 1.0 / np.maximum(t, start)) / (span if span else 1.0)
  return np.where(t <= t_in, linear, beyond)


@pytest.mark.parametrize("fraction", [0.5, 0.25])
def test_unbounded_matches_brute_force(fraction):
  t = _unbounded(fraction=fraction)
  s = _reference_strata(None)
  for r in range(U_RAYS):
    expected = _reference_unbounded(U_NEAR[r], U_INNER[r], U_FAR[r], s[r], fraction)
    np.testing.assert_allclose(t[r], expected, rtol=2e-6, err_msg=f"ray {r}")


@pytest.mark.parametrize("fraction", [0.5, 0.25])
def test_unbounded_jitter_matches_brute_force_in_s(fraction):
  # Jittered in s as `stratified` is; compared where float32 rounding is uniform: in s, where an
  # edge's rounding of 6e-8·t (or of the disparity formula) is at most ~1e-7.
  key = jax.random.PRNGKey(4)
  t = _unbounded(key, fraction)
  s = _reference_strata(key)
  for r in range(U_RAYS - 1):  # the last ray (near = far) has no s to recover
    got = _to_s(U_NEAR[r], U_INNER[r], U_FAR[r], t[r], fraction)
    np.testing.assert_allclose(got[1:-1], s[r, 1:-1], rtol=0, atol=1e-6, err_msg=f"ray {r}")
  # The jitter moves the edges off the even grid.
  assert not np.allclose(t[0], _unbounded(fraction=fraction)[0])


@pytest.mark.parametrize("use_key", [False, True])
def test_unbounded_edges_sorted_finite_and_pinned(use_key):
  for seed in range(5):
    key = jax.random.PRNGKey(seed) if use_key else None
    t = _unbounded(key)
    assert t.shape == (U_RAYS, S + 1) and t.dtype == np.float32
    assert np.all(np.isfinite(t)) and np.all(np.diff(t, axis=-1) >= 0)
    np.testing.assert_array_equal(t[:, 0], U_NEAR)
    np.testing.assert_array_equal(t[:, -1], np.minimum(U_FAR, np.float32(1e10)))


def test_unbounded_share_and_edge_cases():
  t = _unbounded().astype(np.float64)
  # In then out: half the intervals in [near, t_inner], evenly spaced in t; the other half
  # evenly spaced in disparity out to far (1e10).
  np.testing.assert_allclose(t[0, :9], np.linspace(0.5, 2.5, 9), rtol=1e-6)
  np.testing.assert_allclose(np.diff(1.0 / t[0, 8:]), (1e-10 - 1 / 2.5) / 8, rtol=1e-5)
  # Starting outside (t_inner < near) or leaving at near: all in disparity from near (far = inf
  # and 1e4).
  for r, far in ((1, 1e10), (2, 1e4)):
    np.testing.assert_allclose(np.diff(1.0 / t[r]), (1 / far - 1 / U_NEAR[r]) / S, rtol=1e-5)
  # Never leaving before far: `stratified` between near and far.
  np.testing.assert_allclose(t[3], _strata(near=np.array([0.5] * RAYS, np.float32),
                                           far=np.array([6.0] * RAYS, np.float32))[0], rtol=1e-6)
  # near = 0, a miss: in disparity from 1e-3 (the clamp); near = far: all edges at near.
  assert t[4, 0] == 0.0 and 1e-3 <= t[4, 1] <= 1.1e-3
  np.testing.assert_array_equal(t[6], 3.0)


@pytest.mark.parametrize("t_inner", [2.0, 3.0, 7.5, 40.0])
def test_unbounded_edges_give_finite_gradients_to_the_rays_with_an_infinite_far(t_inner):
  # Far = inf becomes 1e10: at the last edge 1/t_inner + (1e-10 - 1/t_inner)·1 rounds to 0 in
  # float32 (e.g. 0.5 + (-0.5) for t_inner = 2). That edge is pinned to far, but the division's
  # derivative there once gave NaN gradients to t_inner, i.e. to the rays' directions under
  # pose or intrinsics refinement (a run stopped at step 141).
  def edges(t_in):
    return spacing.stratified_unbounded(jnp.float32(0.5), t_in, jnp.float32(jnp.inf), 16, (),
                                        None, 0.5)
  grad = jax.grad(lambda t_in: jnp.sum(jnp.log(edges(t_in))))(jnp.float32(t_inner))
  assert np.isfinite(grad)
  # The linear part's edges move as s/f with t_inner: d/dt_in sum(log t) over s in (0, f] is
  # sum(s/f / t); checked against a central difference in float64 of the same formula.
  t = np.asarray(edges(jnp.float32(t_inner)), np.float64)
  assert np.all(np.isfinite(t)) and t[-1] == 1e10 and np.all(np.diff(t) >= 0)
  s = np.arange(17) / 16.0
  inner = (s > 0) & (s <= 0.5)
  want = np.sum((s[inner] / 0.5) / t[inner])
  beyond = (s > 0.5) & (s < 1)
  v = (s[beyond] - 0.5) / 0.5
  inv = lambda ti: 1.0 / ti + (1e-10 - 1.0 / ti) * v
  h = 1e-6 * t_inner
  want += np.sum(-(np.log(inv(t_inner + h)) - np.log(inv(t_inner - h))) / (2 * h))
  np.testing.assert_allclose(grad, want, rtol=2e-3)
