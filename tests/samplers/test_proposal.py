"""Tests of nerf_jax.samplers.proposal: the envelope's bound, the interlevel loss, resampling.

References are brute force in NumPy float64: every (target, envelope) pair of intervals is tested
for overlap. Overlap is that of half-open intervals, [a, b) and [c, d) overlap iff a < b, c < d,
c < b and a < d: intervals sharing only an edge do not overlap, zero-width ones overlap nothing.
Data come from fixed seeds; the library is called through a few jitted functions.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.samplers import proposal
from nerf_jax.samplers import spacing
from tests.helpers import loss_ref, outer_ref, overlaps

pytestmark = pytest.mark.usefixtures("debug_nans")  # conftest.py: a NaN anywhere raises

EPS = proposal._EPS  # pylint: disable=protected-access
outer = jax.jit(proposal.outer)
loss = jax.jit(proposal.interlevel_loss)
resample = jax.jit(proposal.resample, static_argnums=(2,), static_argnames=("method",))
loss_grads = jax.jit(jax.grad(lambda *a: jnp.sum(proposal.interlevel_loss(*a)), (0, 1, 2, 3)))


# Brute-force references (float64; outer_ref and loss_ref are in tests/helpers.py).

def loss_grad_ref(t, w, t_env, w_env):
  """d loss / d w_env: float64 [..., M]; -2·excess_i/(w_i + eps) from every target interval i
  that a non-empty envelope interval j overlaps."""
  t, w, t_env = (np.asarray(a, np.float64) for a in (t, w, t_env))
  excess = np.maximum(w - outer_ref(t, t_env, w_env), 0.0)
  slope = -2.0 * excess / (w + EPS)
  grad = np.zeros(np.shape(w_env))
  for r in np.ndindex(*grad.shape[:-1]):
    for j in range(grad.shape[-1]):
      for i in range(w.shape[-1]):
        if overlaps(t[r][i], t[r][i + 1], t_env[r][j], t_env[r][j + 1]):
          grad[r][j] += slope[r][i]
  return grad


# Data.

def _edges(rng, batch, n, lo=0.0, hi=1.0, share=None, zero_width=0.2):
  """Sorted float32 edges [*batch, n + 1] in [lo, hi] with the ends exactly lo and hi. About a
  fraction `zero_width` of the intervals have zero width; with `share` ([*batch, K] edges), about
  a third of the interior edges are copied from it (edges shared with another step function)."""
  e = rng.uniform(lo, hi, (*batch, n + 1)).astype(np.float32)
  if share is not None:
    picks = np.take_along_axis(share, rng.integers(0, share.shape[-1], e.shape), axis=-1)
    e = np.where(rng.uniform(size=e.shape) < 1 / 3, picks, e)
  e = np.sort(e, axis=-1)
  for k in range(1, n + 1):
    e[..., k] = np.where(rng.uniform(size=batch) < zero_width, e[..., k - 1], e[..., k])
  e[..., 0], e[..., -1] = lo, hi
  return np.sort(e, axis=-1)


def _weights(rng, edges, zero=0.3):
  """Compositing-like weights float32 [..., n] for edges [..., n + 1]: random, about a fraction
  `zero` of them 0, always 0 on zero-width intervals, sum 0.9 per ray (less than 1, as a ray
  that is not fully opaque)."""
  w = rng.uniform(size=edges[..., 1:].shape) * (rng.uniform(size=edges[..., 1:].shape) > zero)
  w = np.where(edges[..., 1:] > edges[..., :-1], w, 0.0)
  return (0.9 * w / np.maximum(w.sum(-1, keepdims=True), 1e-12)).astype(np.float32)


BATCH = (2, 3)
SIZES = [(1, 1), (1, 7), (6, 1), (9, 23), (24, 8)]  # (S target intervals, M envelope intervals)


def _pair(seed, s, m):
  """A target (t, w) and an envelope (t_env, w_env) on rays BATCH: on [0, 1] both, except on
  the last ray, where the target reaches past the envelope on both sides ([-0.5, 1.5])."""
  rng = np.random.default_rng(seed)
  t_env = _edges(rng, BATCH, m)
  t = _edges(rng, BATCH, s, share=t_env)
  t[-1, -1] = _edges(rng, (), s, lo=-0.5, hi=1.5, share=t_env[-1, -1])
  return t, _weights(rng, t), t_env, _weights(rng, t_env)


@pytest.mark.parametrize("s, m", SIZES)
def test_outer_matches_brute_force(s, m):
  t, _, t_env, w_env = _pair(s * 100 + m, s, m)
  got = np.asarray(outer(t, t_env, w_env))
  assert got.shape == (*BATCH, s) and got.dtype == np.float32
  # Cumulative sums of weights summing to 0.9: differences are exact to a few float32 ulps of 1.
  np.testing.assert_allclose(got, outer_ref(t, t_env, w_env), rtol=0, atol=1e-6)
  # The test data has what it claims: shared edges and zero-width intervals on both sides.
  assert np.any(np.isin(t[..., 1:-1], t_env)) or s == 1
  assert np.any(np.diff(t) == 0) and np.any(np.diff(t_env) == 0) or min(s, m) < 6


def test_outer_hand_cases():
  # Envelope [0, 1), [1, 2), [2, 2) (empty), [2, 4) with weights 1, 2, 8, 4.
  t_env = np.array([0, 1, 2, 2, 4], np.float32)
  w_env = np.array([1, 2, 8, 4], np.float32)
  cases = {(0, 1): 1, (0.5, 1): 1, (1, 2): 2, (0.5, 1.5): 3, (2, 2): 0, (1.5, 2.5): 6,
           (2, 3): 4, (-1, 0): 0, (4, 5): 0, (-1, 5): 7, (1, 1.5): 2, (0.99, 1.01): 3}
  for (a, b), want in cases.items():
    got = outer(np.array([a, b], np.float32), t_env, w_env)
    np.testing.assert_array_equal(got, [want], err_msg=str((a, b)))


def test_outer_broadcasts_leading_axes():
  t, _, t_env, w_env = _pair(7, 9, 23)
  got = outer(t[:, :1], t_env[:1], w_env[:1])  # [2, 1, ...] against [1, 3, ...]
  want = outer(np.broadcast_to(t[:, :1], (2, 3, 10)), np.broadcast_to(t_env[:1], (2, 3, 24)),
               np.broadcast_to(w_env[:1], (2, 3, 23)))
  np.testing.assert_array_equal(got, want)


def _intermediate_sizes(jaxpr):
  """Element counts of every value computed in a jaxpr, nested jaxprs included."""
  for eqn in jaxpr.eqns:
    yield from (int(np.prod(v.aval.shape)) for v in eqn.outvars)
    for param in eqn.params.values():
      for sub in param if isinstance(param, (tuple, list)) else (param,):
        sub = getattr(sub, "jaxpr", sub)
        if hasattr(sub, "eqns"):
          yield from _intermediate_sizes(sub)


def test_outer_builds_no_pairwise_array():
  # O((S + M) log M): no value as large as S·M, as a pairwise comparison would make.
  s = m = 512
  jaxpr = jax.make_jaxpr(proposal.outer)(jnp.zeros((1, s + 1)), jnp.zeros((1, m + 1)),
                                         jnp.zeros((1, m)))
  assert max(_intermediate_sizes(jaxpr.jaxpr)) < 4 * (s + m)


@pytest.mark.parametrize("s, m", SIZES)
def test_loss_matches_brute_force(s, m):
  t, w, t_env, w_env = _pair(s * 100 + m + 1, s, m)
  got = np.asarray(loss(t, w, t_env, w_env))
  assert got.shape == BATCH and got.dtype == np.float32
  want = loss_ref(t, w, t_env, w_env)
  # d(term)/d(outer) <= 2, outer exact to ~1e-6: <= 2e-6 per interval.
  np.testing.assert_allclose(got, want, rtol=1e-5, atol=2e-6 * s)
  if min(s, m) > 1:
    assert np.max(want) > 1e-3  # random envelopes do not bound their targets


def _coarsening(rng, t, w, m):
  """An envelope whose every interval is a union of target intervals and holds their weight: m
  intervals on each ray, edges a random subset of the target's, ends included."""
  s = t.shape[-1] - 1
  idx = np.stack([np.r_[0, np.sort(rng.choice(np.arange(1, s), m - 1, replace=False)), s]
                  for _ in range(t.shape[0])])
  cum = np.concatenate([np.zeros((t.shape[0], 1)), np.cumsum(w, -1, dtype=np.float64)], -1)
  w_env = np.diff(np.take_along_axis(cum, idx, -1), axis=-1)
  return np.take_along_axis(t, idx, -1), w_env.astype(np.float32)


@pytest.mark.parametrize("m", [1, 5, 32])  # one interval, a few, the target's own (m = S)
def test_coarsened_envelope_bounds_the_target(m):
  rng = np.random.default_rng(m)
  s, rays = 32, 4
  t = _edges(rng, (rays,), s, lo=2.0, hi=6.0)  # with zero-width intervals, weight 0 on them
  w = _weights(rng, t)
  t_env, w_env = _coarsening(rng, t, w, m)
  assert np.all(np.asarray(outer(t, t_env, w_env)) >= w - 1e-6)
  np.testing.assert_allclose(loss(t, w, t_env, w_env), 0.0, atol=1e-6)

  # Less weight than the target somewhere: the loss sees each shortfall. The heaviest envelope
  # interval emptied: its target intervals are bounded by 0, loss = their sum of w²/(w + eps).
  heaviest = np.argmax(w_env, axis=-1)[:, None]
  inside = (t[:, 1:] > np.take_along_axis(t_env, heaviest, -1)) & (
      t[:, :-1] < np.take_along_axis(t_env, heaviest + 1, -1))
  short = np.where(np.arange(m) == heaviest, 0.0, w_env).astype(np.float32)
  want = np.sum(np.where(inside, w.astype(np.float64) ** 2 / (w + EPS), 0.0), -1)
  np.testing.assert_allclose(loss(t, w, t_env, short), want, rtol=1e-5, atol=1e-6)
  assert np.all(want > 0.05)
  # Every envelope weight halved: a target interval alone in its envelope interval (m = S) is
  # short by w/2 (elsewhere the halved weight of a union of intervals may still bound each one).
  if m == s:
    got = loss(t, w, t_env, 0.5 * w_env)
    np.testing.assert_allclose(got, np.sum(0.25 * w.astype(np.float64) ** 2 / (w + EPS), -1),
                               rtol=1e-5)
    assert np.all(got > 0.05)


def _hot(e, k):
  """One-hot weights float32 [rays, n] for edges e [rays, n + 1]: 1 on interval k[r] of ray r."""
  return (np.arange(e.shape[-1] - 1) == np.asarray(k)[:, None]).astype(np.float32)


def _far_edges(rng, rays, n, share=None):
  """`_edges` spread log-uniformly over [0.5, 1e10], as an unbounded scene's (most are huge)."""
  lo, hi = np.log(0.5), np.log(spacing.MAX_FAR)
  log_share = None if share is None else np.log(share.astype(np.float64)).astype(np.float32)
  e = np.exp(_edges(rng, (rays,), n, lo, hi, log_share).astype(np.float64)).astype(np.float32)
  e[:, 0], e[:, -1] = 0.5, spacing.MAX_FAR
  return np.sort(e, axis=-1)


def _hard_cases():
  """(name, (t, w, t_env, w_env)) on 4 rays, all with zero-width intervals and shared edges:
  random; all-zero weights (either or both); one-hot weights, the target's on its widest interval
  and the envelope's away from it; edges out to 1e10 (log-uniform: most are huge), random weights
  and one-hot weights on the target's widest interval and the envelope's nearest."""
  rng = np.random.default_rng(5)
  s, m, rays = 16, 12, 4
  t_env = _edges(rng, (rays,), m, lo=0.5, hi=8.0)
  t = _edges(rng, (rays,), s, lo=0.5, hi=8.0, share=t_env)
  yield "random", (t, _weights(rng, t), t_env, _weights(rng, t_env))
  zeros = lambda e: np.zeros_like(e[..., 1:])
  yield "all zero", (t, zeros(t), t_env, zeros(t_env))
  yield "target zero", (t, zeros(t), t_env, _weights(rng, t_env))
  yield "envelope zero", (t, _weights(rng, t), t_env, zeros(t_env))
  # The envelope's weight on the end away from the target's, so it does not bound it.
  widest = np.argmax(np.diff(t), -1)
  far_end = np.where(t[np.arange(rays), widest] < 4.25, m - 1, 0)
  yield "one-hot", (t, _hot(t, widest), t_env, _hot(t_env, far_end))
  t_env_far = _far_edges(rng, rays, m)
  t_far = _far_edges(rng, rays, s, share=t_env_far)
  assert np.sum(t_far > 1e6) > 4 * rays and np.any(np.diff(t_far) == 0)
  yield "far", (t_far, _weights(rng, t_far), t_env_far, _weights(rng, t_env_far))
  hot_far = _hot(t_far, np.argmax(np.diff(t_far), -1))
  yield "far one-hot", (t_far, hot_far, t_env_far, _hot(t_env_far, [0] * rays))


@pytest.mark.parametrize("name, args", list(_hard_cases()))
def test_loss_gradients_finite_and_only_to_the_envelope(name, args):
  value = np.asarray(loss(*args))
  g_t, g_w, g_t_env, g_w_env = (np.asarray(g) for g in loss_grads(*args))
  assert np.all(np.isfinite(value)) and np.all(np.isfinite(g_w_env)), name
  np.testing.assert_allclose(value, loss_ref(*args), rtol=1e-5, atol=4e-5)
  # The target is under stop_gradient; edges are only compared.
  for g in (g_t, g_w, g_t_env):
    np.testing.assert_array_equal(g, 0.0)
  # |d term/d outer| <= 2: a few float32 ulps of 2 per overlapping target interval.
  np.testing.assert_allclose(g_w_env, loss_grad_ref(*args), rtol=1e-5, atol=1e-5)
  if name in ("envelope zero", "one-hot", "far one-hot"):
    assert np.all(value > 0.5) and np.all(np.min(g_w_env, -1) < -1.0)  # pushes the bound up


# resample: N_NEW new intervals on the rays of `_hard_cases` (one compilation per key or None).

N_NEW = 32


def _check_edges(new, t, n):
  assert new.shape == (*t.shape[:-1], n + 1) and new.dtype == np.float32
  assert np.all(np.diff(new, axis=-1) >= 0)
  np.testing.assert_array_equal(new[..., 0], t[..., 0])
  np.testing.assert_array_equal(new[..., -1], t[..., -1])


@pytest.mark.parametrize("name, args", list(_hard_cases()))
@pytest.mark.parametrize("seed, method", [(None, "sorted_uniform"), (0, "sorted_uniform"),
                                          (0, "jittered_grid")])
def test_resample_sorted_inside_and_ends_kept(name, args, seed, method):
  key = None if seed is None else jax.random.PRNGKey(seed)
  t, w = args[:2]
  for n in (1, N_NEW):
    new = np.asarray(resample(t, w, n, key, method=method))
    _check_edges(new, t, n)
    assert np.all(np.isfinite(new)), name


def _mass(t, w, x):
  """The share of the step function (t, w) [S + 1], [S] below each x, float64."""
  cdf = np.r_[0.0, np.cumsum(w, dtype=np.float64)]
  return np.interp(np.asarray(x, np.float64), t.astype(np.float64), cdf / cdf[-1])


def test_resample_deterministic_edges_are_equal_mass_quantiles():
  n = 12
  t = np.linspace(2.0, 6.0, 9, dtype=np.float32)
  new = np.asarray(resample(t[None], np.full((1, 8), 0.1, np.float32), n))
  np.testing.assert_allclose(new[0], np.linspace(2.0, 6.0, n + 1), rtol=0, atol=2e-6)
  # Half the mass on [2, 3), half on [3, 6): every new interval holds 1/N of it, but for the two
  # at the jump in density, whose shared edge lies between the neighbouring points (midpoint in t,
  # not in mass): they hold between 1/2N and 3/2N.
  w = np.array([0.3, 0.3, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1], np.float32)
  new = np.asarray(resample(t[None], w[None], n, padding=0.0))[0]
  mass = np.diff(_mass(t, w, new))
  jump = np.searchsorted(new, 3.0)  # new interval jump - 1 and jump meet near t = 3
  regular = np.delete(mass, [jump - 1, jump])
  np.testing.assert_allclose(regular, 1 / n, rtol=0, atol=1e-6)
  assert np.all((mass[[jump - 1, jump]] > 0.5 / n) & (mass[[jump - 1, jump]] < 1.5 / n)), mass


@pytest.mark.parametrize("seed", [None, 3])
def test_resample_concentrates_where_the_weight_is(seed):
  key = None if seed is None else jax.random.PRNGKey(seed)
  s, n, rays, hot = 16, N_NEW, 4, 5
  t = np.broadcast_to(np.linspace(2.0, 6.0, s + 1, dtype=np.float32), (rays, s + 1))
  w = np.broadcast_to((np.arange(s) == hot).astype(np.float32), (rays, s))
  inside = lambda e: (e >= t[0, hot]) & (e <= t[0, hot + 1])
  # Without padding every interior edge lies in the hot interval.
  new = np.asarray(resample(t, w, n, key, padding=0.0))
  _check_edges(new, t, n)
  assert np.all(inside(new[:, 1:-1]))
  # With nerfacto's padding 0.01 per interval the hot one holds 1.01/1.16 = 87% of the mass.
  new = np.asarray(resample(t, w, n, key))
  share = np.mean(inside(new[:, 1:-1]))
  assert share > 1.01 / 1.16 - (0.03 if seed is None else 0.1), share


def test_resampled_intervals_hold_equal_weight_on_the_jittered_grid():
  """In the spirit of multinerf's test_sample_intervals_accuracy: over random step functions
  (16 intervals of exponential widths, weights exp(2·N(0, 1)), no padding), the mass of each of
  N = 128 resampled intervals, times N, against 1 (its share). The metric, mean |N·mass - 1|
  over 256 rays and all intervals, measured: 'jittered_grid' 0.033 (as the deterministic
  quantiles, 0.030: only the intervals whose midpoint edge falls between two points in
  different intervals of the step function miss 1/N), 'sorted_uniform' 0.55 (the gaps of
  sorted uniforms, exponential about 1/N)."""
  rng = np.random.default_rng(6)
  rays, s, n = 256, 16, 128
  widths = rng.exponential(size=(rays, s))
  t = np.float32(2.0 + np.concatenate([np.zeros((rays, 1)), np.cumsum(widths, -1)], -1))
  w = np.float32(np.exp(2.0 * rng.normal(size=(rays, s))))

  def shares(key, method):
    new = np.asarray(resample(t, w, n, key, 0.0, method=method))
    _check_edges(new, t, n)
    return n * np.diff(np.stack([_mass(a, b, e) for a, b, e in zip(t, w, new)]), axis=-1)

  key = jax.random.PRNGKey(7)
  grid, uniform = shares(key, "jittered_grid"), shares(key, "sorted_uniform")
  fixed = shares(None, "jittered_grid")
  np.testing.assert_array_equal(fixed, shares(None, "sorted_uniform"))  # key None: one path
  error = {name: np.mean(np.abs(x - 1.0)) for name, x in
           (("jittered_grid", grid), ("sorted_uniform", uniform), ("none", fixed))}
  assert error["jittered_grid"] < 0.1, error
  assert error["jittered_grid"] < error["none"] + 0.01, error
  assert error["sorted_uniform"] > 0.4, error
  # One offset δ per ray, uniform in [0, 1): the first interval holds (1/2 + δ)/N (where its
  # two points share an interval of the step function), spread over the rays as U[0.5, 1.5).
  first = grid[:, 0]
  assert abs(np.median(first) - 1.0) < 0.1 and 0.2 < np.std(first) < 0.45, (first.mean(),
                                                                              first.std())
  with pytest.raises(ValueError, match="resample"):
    proposal.Settings(resample="stratified")


def test_resample_keys_and_stopped_gradients():
  t, w = next(_hard_cases())[1][:2]
  n = N_NEW
  a, b = resample(t, w, n, jax.random.PRNGKey(0)), resample(t, w, n, jax.random.PRNGKey(0))
  np.testing.assert_array_equal(a, b)
  assert not np.allclose(a, resample(t, w, n, jax.random.PRNGKey(1)))
  np.testing.assert_array_equal(resample(t, w, n), resample(t, w, n))
  grads = jax.jit(jax.grad(lambda t, w: jnp.sum(proposal.resample(t, w, n)), (0, 1)))(t, w)
  for g in grads:
    np.testing.assert_array_equal(g, 0.0)
