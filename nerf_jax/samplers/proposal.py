"""Step-function math of a proposal sampler (mip-NeRF 360, nerfacto): the envelope's bound,
the interlevel loss, resampling. (The sampler that uses them, handed the proposal density
fields, is the next step of issue 39.)

A proposal network predicts a cheap density along each ray. Its weights, a step function over its
own intervals (the envelope), place the samples of the next level (a finer proposal or the NeRF,
the target) and are trained to bound the target's weights. Names and axes, for rays [...]:

  t:     float32 [..., S + 1] sorted interval edges of the target; interval i is [t_i, t_{i+1}).
  w:     float32 [..., S] the target's weights >= 0 (compositing weights, sum <= 1).
  t_env: float32 [..., M + 1] sorted interval edges of the envelope (the proposal).
  w_env: float32 [..., M] the envelope's weights >= 0.

The leading axes [...] of t and of (t_env, w_env) broadcast against each other. Edges are finite
(the samplers cap far at sampling.MAX_FAR = 1e10); the bound and the loss only compare them.

Overlap, as in mip-NeRF 360's definition: intervals are half-open, [a, b), so they tile the ray, and
two intervals overlap iff their intersection is not empty. So intervals that only share an edge do
not overlap, and a zero-width interval is empty and overlaps nothing: the envelope's weight on one
counts nowhere, and a target interval of zero width is bounded by 0 (compositing gives such an
interval zero weight: alpha = 1 - exp(-sigma·0) = 0).

Numerics: all-zero weights give outer = 0, a loss of 0 and zero gradients, and resampling falls
back to evenly spread points (sample_pdf's padding); one-hot weights are no special case (no
logarithm or division by a weight); zero-width intervals are empty as above, and resampling
never divides by their width; huge distances (edges out to 1e10) are only compared by `outer` and
the loss, and resampling only averages two of them.
"""

import jax
import jax.numpy as jnp

from nerf_jax.samplers import sampling

# The loss divides by w + _EPS. Any eps > 0 keeps it finite: the denominator is positive where
# w = 0 (where the numerator is 0 too, as outer >= 0), each term max(0, w - outer)²/(w + eps) is
# at most w and its gradient w.r.t. outer at most 2 in magnitude. 1e-7 is a normal float32 (a GPU
# flushes subnormals to 0) far below the weights that matter, where terms stay (w - outer)²/w.
_EPS = 1e-7


def outer(t, t_env, w_env):
  """The envelope's bound on each target interval: float32 [..., S].

  t: float32 [..., S + 1] sorted target edges. t_env: float32 [..., M + 1] sorted envelope edges.
  w_env: float32 [..., M] envelope weights >= 0. Entry i is the sum of w_env_j over the envelope
  intervals [t_env_j, t_env_{j+1}) that overlap [t_i, t_{i+1}) (see the module doc): mip-NeRF
  360's outer measure, an upper bound of any weight the same density puts on interval i.
  O((S + M) log M) per ray: two binary searches per target edge and a cumulative sum.
  """
  batch = jnp.broadcast_shapes(t.shape[:-1], t_env.shape[:-1], w_env.shape[:-1])
  t, t_env, w_env = (jnp.broadcast_to(a, (*batch, a.shape[-1])) for a in (t, t_env, w_env))
  # An empty envelope interval overlaps nothing: its weight counts nowhere.
  w_env = jnp.where(t_env[..., 1:] > t_env[..., :-1], w_env, 0.0)
  zero = jnp.zeros_like(w_env[..., :1])
  cum = jnp.concatenate([zero, jnp.cumsum(w_env, axis=-1)], axis=-1)  # sum of w_env_j, j < k
  # [e_j, e_{j+1}) overlaps [a, b) (a < b) iff e_j < b and e_{j+1} > a, i.e. for j in
  # [lo - 1, hi) with lo = #{e <= a}, hi = #{e < b}; clipped to [0, M), lo - 1 <= hi.
  lo = _count(t_env, t[..., :-1], "right")
  hi = _count(t_env, t[..., 1:], "left")
  first = jnp.maximum(lo - 1, 0)
  last = jnp.minimum(hi, w_env.shape[-1])
  total = _take(cum, last) - _take(cum, first)
  # >= 0 exactly; the clamp undoes rounding of a cumulative sum evaluated as a parallel scan. A
  # `where`, not jnp.maximum: at total = 0 (an empty envelope) the gradient stays 1, not 1/2.
  total = jnp.where(total < 0.0, 0.0, total)
  return jnp.where(t[..., 1:] > t[..., :-1], total, 0.0)


def _count(edges, x, side):
  """Per ray, how many edges [..., K] are < x (side 'left') or <= x ('right'): int [..., Q]."""
  flat_edges = edges.reshape(-1, edges.shape[-1])
  flat_x = x.reshape(-1, x.shape[-1])
  count = jax.vmap(lambda e, v: jnp.searchsorted(e, v, side=side))(flat_edges, flat_x)
  return count.reshape(x.shape)


def _take(a, idx):
  return jnp.take_along_axis(a, idx, axis=-1)


def interlevel_loss(t, w, t_env, w_env):
  """mip-NeRF 360's proposal loss per ray: float32 [...].

  t: float32 [..., S + 1] sorted target edges. w: float32 [..., S] target weights >= 0.
  t_env: float32 [..., M + 1] sorted envelope edges. w_env: float32 [..., M] envelope weights.
  Returns sum_i max(0, w_i - outer_i)² / (w_i + eps), outer = `outer(t, t_env, w_env)`: 0 where
  the envelope bounds the target everywhere. The target is under stop_gradient (only the envelope
  is trained by this loss); edges get no gradient anyway (they are only compared). Finite, with
  finite gradients, for any finite inputs of this form (see _EPS); a weight on a zero-width target
  interval adds the constant w²/(w + eps).
  """
  t = jax.lax.stop_gradient(t)
  w = jax.lax.stop_gradient(jnp.maximum(w, 0.0))  # >= 0 keeps w + eps >= eps
  excess = jnp.maximum(w - outer(t, t_env, w_env), 0.0)
  return jnp.sum(excess * excess / (w + _EPS), axis=-1)


def resample(t, w, num_samples, key=None, padding=0.01):
  """The next level's edges, drawn from the step function (t, w): float32 [..., N + 1].

  t: float32 [..., S + 1] sorted edges. w: float32 [..., S] weights >= 0. num_samples: int N >= 1.
  key: PRNG key, or None for deterministic edges. padding: float, added to every non-empty
  interval's weight before normalising (`sampling.sample_pdf`; 0.01 as nerfacto's).
  Returns sorted edges with t_0 and t_S exactly at the ends, gradients stopped.

  N points are drawn with `sampling.sample_pdf` (key None: at the quantiles (k + 1/2)/N; with a
  key: at N sorted uniform draws) and the interior edges are the midpoints between consecutive
  points: where both lie in one interval of (t, w), at the quantile k/N, so each new interval
  holds ~1/N of the (padded) weight. Zero-width intervals get no points (sample_pdf), all-zero
  weights give points evenly spread over the intervals (padding > 0) or over t (padding = 0).
  """
  t = jax.lax.stop_gradient(t)
  points = sampling.sample_pdf(t, w, num_samples, key, padding)  # sorted, in [t_0, t_S]
  # 0.5·(a + b) lies in [a, b] for floats a <= b (rounding is monotone, halving a normal float is
  # exact, no overflow for edges <= 1e10), so the edges stay sorted and inside [t_0, t_S].
  inner = 0.5 * (points[..., 1:] + points[..., :-1])
  return jnp.concatenate([t[..., :1], inner, t[..., -1:]], axis=-1)
