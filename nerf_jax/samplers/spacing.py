"""How samples are spaced along rays: stratified and inverse-CDF draws of their distances
(where the built-in Sampler puts them is placement.py).

A ray's samples are described by sorted interval edges `t: float32 [..., S + 1]`: sample i covers
[t_i, t_{i+1}] and is evaluated at its midpoint. t is the ray parameter (z-depth, see rays.py)
and is always float32, whatever precision the network runs in.
`stratified` spaces edges between near and far; `stratified_unbounded` does so for rays into an
unbounded scene (linear in t inside the contraction's inner region, linear in disparity beyond it,
out to far = inf; `unbounded_unit` is its inverse); `sample_pdf` draws new edges from the
weights of a first pass.
"""

import jax
import jax.numpy as jnp

from nerf_jax.backend import draws
from nerf_jax.cameras.scene_settings import SceneSettings

# Smallest near bound used by linear-in-disparity sampling: 1/near must stay finite.
_MIN_NEAR_LINDISP = 1e-3

# The last edge of `stratified_unbounded` for far = inf (and any far beyond it). An edge at
# infinity would make the last interval infinite, and sigma·inf is NaN for sigma = 0 (and inf·0
# in the backward pass). 1e10 is as good as infinity to a float32 contraction (it rounds every
# |x| > 2^24·radius onto the outer boundary), and `compositing.composite` stays finite over such
# an interval (tests/topics/test_numerics.py, case 13).
MAX_FAR = 1e10


def midpoints(t):
  """Sample positions: float32 [..., S] midpoints of the intervals of `t: [..., S + 1]`."""
  return 0.5 * (t[..., 1:] + t[..., :-1])


def stratified(near, far, num_samples, batch_shape, key=None, lindisp=False):
  """Stratified interval edges between near and far.

  near, far: float or float32 broadcastable to batch_shape, 0 <= near <= far. num_samples: int S.
  batch_shape: tuple, leading shape of the rays. key: PRNG key, or None for evenly spaced edges.
  lindisp: space the edges evenly in 1/t (inverse depth) instead of t.
  Returns t: float32 [*batch_shape, S + 1], sorted, t_0 = near and t_S = far exactly. With a key,
  every interior edge is drawn uniformly between the midpoints of its neighbouring strata, so each
  sample's midpoint lies in its own stratum and the intervals still tile [near, far].
  near == far gives S zero-width intervals (composited as an empty ray). With lindisp, near is
  clamped to 1e-3 inside the formula (1/0 = inf), so for near = 0 the first interval is
  [0, ~1e-3·S/(S-1)]; all edges are clipped to [near, far].
  """
  near = jnp.broadcast_to(jnp.asarray(near, jnp.float32), batch_shape)[..., None]
  far = jnp.broadcast_to(jnp.asarray(far, jnp.float32), batch_shape)[..., None]
  s = _unit_strata(num_samples, batch_shape, key)
  # Both maps below are compositions of monotone roundings of s, so the edges stay sorted even
  # when near and far are a few ulps apart (near·(1 - s) + far·s is not monotone then).
  if lindisp:
    inv_near = 1.0 / jnp.maximum(near, _MIN_NEAR_LINDISP)
    inv_far = 1.0 / jnp.maximum(far, _MIN_NEAR_LINDISP)
    t = 1.0 / (inv_near + (inv_far - inv_near) * s)
  else:
    t = near + (far - near) * s
  # Clipping (monotone) undoes the near clamp above and rounding past far; then pin the ends.
  t = jnp.clip(t, near, far)
  return t.at[..., 0].set(near[..., 0]).at[..., -1].set(far[..., 0])


def _unit_strata(num_samples, batch_shape, key):
  """Stratified positions in [0, 1]: float32 [*batch_shape, S + 1], sorted, exactly 0 and 1 at
  the ends. key None: evenly spaced k/S; otherwise every interior edge is drawn uniformly between
  the midpoints of its neighbouring strata (so the intervals' midpoints keep to their strata)."""
  s = jnp.linspace(0.0, 1.0, num_samples + 1, dtype=jnp.float32)
  s = jnp.broadcast_to(s, (*batch_shape, num_samples + 1))
  if key is not None:
    mids = 0.5 * (s[..., 1:] + s[..., :-1])
    lower = jnp.concatenate([s[..., :1], mids], axis=-1)
    upper = jnp.concatenate([mids, s[..., -1:]], axis=-1)
    u = draws.uniform(key, s.shape, jnp.float32)
    s = lower + (upper - lower) * u
    # lower + (upper - lower)·u can round one ulp past upper; cummax keeps the edges sorted.
    s = jax.lax.cummax(s, axis=s.ndim - 1)
  return s


def _unbounded_split(near, t_inner, far, inner_fraction, batch_shape):
  """(near, t_in, far, f), each float32 [*batch_shape, 1]: a ray's bounds (far capped at
  MAX_FAR), where it leaves the inner region (clamped into [near, far]) and the share f of s
  given to [near, t_in], as `stratified_unbounded` defines them."""
  shape = lambda a: jnp.broadcast_to(jnp.asarray(a, jnp.float32), batch_shape)[..., None]
  near = shape(near)
  far = jnp.minimum(shape(far), MAX_FAR)
  t_in = jnp.clip(shape(t_inner), near, far)
  f = jnp.where(t_in <= near, 0.0, jnp.where(t_in >= far, 1.0, shape(inner_fraction)))
  return near, t_in, far, f


def stratified_unbounded(near, t_inner, far, num_samples, batch_shape, key=None,
                         inner_fraction=SceneSettings.inner_fraction):
  """Stratified edges for rays into an unbounded scene: linear in t, then linear in disparity.

  Inside the contraction's inner region (`nerf_jax.fields.contraction`) space is not squeezed and
  the edges are evenly spaced in t; beyond it, where contracted space shrinks like 1/t, they are
  evenly spaced in disparity 1/t (nerfstudio's piecewise uniform / linear-in-disparity sampler
  with a per-ray split). With f the ray's inner share (below), the edges are t(s) for
  stratified s in [0, 1] (`stratified`'s strata and jitter, in s):
    s in [0, f]:  t = near + (t_inner - near)·s/f                      (linear in t),
    s in [f, 1]:  1/t = 1/t_inner + (1/far - 1/t_inner)·(s - f)/(1 - f)  (linear in 1/t).

  near: float or float32 broadcastable to batch_shape, >= 0. t_inner: float or float32
  broadcastable to batch_shape, where the ray leaves the inner region (`contraction.inner_exit`);
  clamped into [near, far]. far: float or float32 broadcastable to batch_shape, may be huge or inf:
  replaced by min(far, MAX_FAR = 1e10), so the last edge is finite. num_samples: int S.
  batch_shape: tuple. key: PRNG key, or None for evenly spaced s. inner_fraction: float in
  [0, 1] (or float32 broadcastable to batch_shape), the share f of s given to [near, t_inner].
  Returns t: float32 [*batch_shape, S + 1], sorted and finite, t_0 = near and
  t_S = min(far, 1e10) exactly.

  Per ray, f = inner_fraction where near < t_inner < far; f = 0 (all samples in disparity from
  near) where t_inner <= near, i.e. the ray starts outside the region or misses it; f = 1 (all
  linear, as `stratified`) where t_inner >= far. The disparity part starts at max(t_inner, 1e-3)
  inside the formula (1/0 = inf, as `stratified`'s lindisp) and is clipped to [t_inner, far].
  """
  near, t_in, far, f = _unbounded_split(near, t_inner, far, inner_fraction, batch_shape)
  s = _unit_strata(num_samples, batch_shape, key)
  # Each branch is a composition of monotone roundings of s, clipped to its own range, and the
  # ranges [near, t_in] and [t_in, far] meet at t_in: the edges stay sorted. The safe divisors
  # are only used where their branch is discarded (f = 0: s <= f only at s = 0; f = 1: no s > f).
  linear = near + (t_in - near) * (s / jnp.where(f > 0.0, f, 1.0))
  linear = jnp.clip(linear, near, t_in)
  v = (s - f) / jnp.where(f < 1.0, 1.0 - f, 1.0)
  inv_start = 1.0 / jnp.maximum(t_in, _MIN_NEAR_LINDISP)
  inv_far = 1.0 / jnp.maximum(far, _MIN_NEAR_LINDISP)
  # v <= 1 keeps the denominator >= inv_far > 0; v < 0 (the discarded branch) makes it larger.
  # In float32, inv_start + (inv_far - inv_start)·1 can round to 0 (inv_far = 1e-10 is below
  # inv_start's last bit): 1/0 = inf, clipped, but its derivative -1/0² times a zero cotangent is
  # a NaN gradient for the rays (pose and intrinsics refinement). The floor at inv_far, its exact
  # value, changes no edge otherwise.
  denominator = jnp.maximum(inv_start + (inv_far - inv_start) * v, inv_far)
  disparity = jnp.clip(1.0 / denominator, t_in, far)
  t = jnp.where(s <= f, linear, disparity)
  return t.at[..., 0].set(near[..., 0]).at[..., -1].set(far[..., 0])


def unbounded_unit(t, near, t_inner, far, inner_fraction=SceneSettings.inner_fraction):
  """The inverse of `stratified_unbounded`'s map s -> t: s float32 [..., K] in [0, 1] at
  distances t float32 [..., K] (clipped to [near, min(far, MAX_FAR)]). near, t_inner, far,
  inner_fraction: as `stratified_unbounded`, broadcastable to t's batch shape [...]. Its edges
  map back onto evenly spaced s (key None), and every distance onto the share of the ray's
  samples before it: the normalised ray distance of mip-NeRF 360's distortion loss.
  """
  near, t_in, far, f = _unbounded_split(near, t_inner, far, inner_fraction, t.shape[:-1])
  t = jnp.clip(t, near, far)
  # The safe divisors are only used where their branch is discarded: t_in = near gives f = 0
  # (the linear branch only at t = near), t_in = far means no t beyond t_in.
  linear = f * (t - near) / jnp.where(t_in > near, t_in - near, 1.0)
  inv_start = 1.0 / jnp.maximum(t_in, _MIN_NEAR_LINDISP)
  inv_far = 1.0 / jnp.maximum(far, _MIN_NEAR_LINDISP)
  span = jnp.where(inv_start > inv_far, inv_start - inv_far, 1.0)
  disparity = f + (1.0 - f) * (inv_start - 1.0 / jnp.maximum(t, _MIN_NEAR_LINDISP)) / span
  return jnp.clip(jnp.where(t <= t_in, linear, disparity), 0.0, 1.0)


def sample_pdf(t, weights, num_samples, key=None, padding=0.01, jittered_grid=False):
  """Draw new distances by inverse-CDF sampling of a piecewise-constant density.

  t: float32 [..., S + 1] interval edges. weights: float32 [..., S] non-negative weight of each
  interval. num_samples: int N. key: PRNG key, or None for the deterministic quantiles
  (u = (k + 0.5)/N). padding: float, added to every weight before normalising.
  jittered_grid: with a key, the quantiles u = (k + δ)/N, one δ ~ U[0, 1) per ray (the grid
  shifted at random: mip-NeRF 360's and nerfacto's single jitter, multinerf's
  stepfun.sample(single_jitter=True)); False: N independent uniforms, sorted (NeRF's).
  Returns float32 [..., N] sorted distances inside [t_0, t_S], with gradients stopped.

  Safety: `padding` keeps the density strictly positive, so all-zero weights give uniform samples
  and the CDF never has a zero total (with padding = 0 and no mass at all the density falls back
  to uniform in t); zero-width bins get no mass, so no sample falls inside them and no division by
  their width occurs; the CDF is a cumulative sum made monotone with cummax and pinned to exactly 0
  and 1 at its ends (the last bin is never skipped by rounding); each sample is clipped to its bin.
  """
  t = jax.lax.stop_gradient(t)
  weights = jax.lax.stop_gradient(weights)
  widths = jnp.maximum(t[..., 1:] - t[..., :-1], 0.0)
  # Zero-width bins hold no mass (padding included).
  weights = jnp.where(widths > 0, jnp.maximum(weights, 0.0) + padding, 0.0)
  total = jnp.sum(weights, axis=-1, keepdims=True)
  # No mass at all (padding = 0 and zero weights): uniform in t instead of piling onto the last bin.
  weights = jnp.where(total > 0, weights, widths)
  total = jnp.sum(weights, axis=-1, keepdims=True)
  # total = 0 only if every bin has zero width; then all samples are t_0 = t_S whatever the pdf.
  pdf = weights / jnp.where(total > 0, total, 1.0)
  cdf = jnp.minimum(1.0, jnp.cumsum(pdf[..., :-1], axis=-1))
  # A cumulative sum need not be exactly monotone when evaluated as a parallel scan.
  cdf = jax.lax.cummax(cdf, axis=cdf.ndim - 1)
  # From pdf (S >= 1 entries), not cdf: with one interval cdf has no entries, and so would these.
  zeros = jnp.zeros_like(pdf[..., :1])
  ones = jnp.ones_like(pdf[..., :1])
  cdf = jnp.concatenate([zeros, cdf, ones], axis=-1)  # [..., S + 1], exactly 0 and 1 at the ends
  batch_shape = t.shape[:-1]
  if key is None:
    u = (jnp.arange(num_samples, dtype=jnp.float32) + 0.5) / num_samples
    u = jnp.broadcast_to(u, (*batch_shape, num_samples))
  elif jittered_grid:
    # (k + δ)/N < 1 for δ < 1; rounding can reach 1 at k = N - 1 for large N, which _invert_cdf
    # takes (u == 1 lands on t_S).
    offset = draws.uniform(key, (*batch_shape, 1), jnp.float32)
    u = (jnp.arange(num_samples, dtype=jnp.float32) + offset) / num_samples
  else:
    u = draws.uniform(key, (*batch_shape, num_samples), jnp.float32)
  samples = _invert_cdf(u, t, cdf)
  return jnp.sort(samples, axis=-1)


def _invert_cdf(u, t, cdf):
  """Piecewise-linear inverse of a CDF given at the edges t.

  u: float32 [..., N] in [0, 1). t, cdf: float32 [..., S + 1], both non-decreasing.
  Returns float32 [..., N] inside [t_0, t_S].
  """
  num_edges = t.shape[-1]
  flat_u = u.reshape(-1, u.shape[-1])
  flat_t = t.reshape(-1, num_edges)
  flat_cdf = cdf.reshape(-1, num_edges)
  # Bin index k with cdf[k] <= u < cdf[k+1]; 'right' skips empty (flat) bins.
  idx = jax.vmap(lambda c, v: jnp.searchsorted(c, v, side="right"))(flat_cdf, flat_u)
  idx = jnp.clip(idx, 1, num_edges - 1)
  take = lambda a, i: jnp.take_along_axis(a, i, axis=-1)
  cdf0, cdf1 = take(flat_cdf, idx - 1), take(flat_cdf, idx)
  t0, t1 = take(flat_t, idx - 1), take(flat_t, idx)
  width = cdf1 - cdf0
  # A bin reached by searchsorted has width > 0, but guard the division for u == 1 exactly.
  frac = jnp.where(width > 0, (flat_u - cdf0) / jnp.where(width > 0, width, 1.0), 0.0)
  # The clip keeps the sample in its bin when t0 + frac·(t1 - t0) rounds past t1.
  samples = jnp.clip(t0 + jnp.clip(frac, 0.0, 1.0) * (t1 - t0), t0, t1)
  return samples.reshape(u.shape)


def merge_edges(t, extra):
  """Union of interval edges t: float32 [..., S + 1] and new edges extra: float32 [..., N].

  Returns float32 [..., S + N + 1], sorted. Both inputs lie in [t_0, t_S] so the ends are kept.
  """
  return jnp.sort(jnp.concatenate([t, extra], axis=-1), axis=-1)
