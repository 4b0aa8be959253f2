"""The volume rendering quadrature: from densities on intervals to optical depth, alpha,
transmittance and the compositing weights. Below the samplers (a proposal sampler resamples
from these weights) and the renderers (render/compositing.py composites with them).

Names and axes:
  t:       float32 [..., S + 1]  sorted interval edges; sample i covers [t_i, t_{i+1}]
  sigma:   float32 [..., S]      volume density of each sample (>= 0, per unit of t)
  tau:     float32 [..., S]      optical depth sigma_i·(t_{i+1} - t_i) of each interval
  weights: float32 [..., S]      w_i = T_i · alpha_i, the probability the ray ends in interval i

Stability (docs/numerics.md): optical depths are summed, never multiplied, so behind an opaque
interval the transmittance underflows to exactly 0; alpha = 1 - exp(-tau) is -expm1(-tau) with
the exact derivative exp(-tau); densities are clamped at MAX_DENSITY so that no 0·inf appears.
"""

import jax
import jax.numpy as jnp

# Densities are clamped here before multiplying by delta. An infinite density (an overflowing
# activation, or float16 inf cast up) times a zero-width interval is inf·0 = NaN, and even with
# delta > 0 the backward pass of tau = sigma·delta computes 0·inf = NaN for d/d delta. 1e30 is
# opaque over any interval longer than 1e-28 and keeps sigma·delta finite for delta < 3e8.
MAX_DENSITY = 1e30


@jax.custom_jvp
def one_minus_exp_neg(x):
  """1 - exp(-x) for x >= 0 (float32 [...]), accurate for tiny x via expm1.

  The custom derivative is exp(-x) itself: the default derivative of expm1 is 1 + expm1(-x), which
  cancels to an absolute error of ~6e-8 (100% relative error once exp(-x) < 6e-8).
  """
  return -jnp.expm1(-x)


@one_minus_exp_neg.defjvp
def _one_minus_exp_neg_jvp(primals, tangents):
  (x,), (x_dot,) = primals, tangents
  return one_minus_exp_neg(x), jnp.exp(-x) * x_dot


def exclusive_cumsum(x):
  """Sum of the preceding entries along the last axis: float32 [..., S] -> [..., S]."""
  return jnp.concatenate([jnp.zeros_like(x[..., :1]), jnp.cumsum(x[..., :-1], axis=-1)], axis=-1)


def compute_weights(sigma, t):
  """Compositing weights.

  sigma: float [..., S], t: float32 [..., S + 1]. Returns (weights, transmittance_end):
  float32 [..., S] and float32 [...], the transmittance left after the last sample.
  """
  weights, total = weights_and_optical_depth(sigma, t)
  return weights, jnp.exp(-total)


def weights_and_optical_depth(sigma, t, exact_derivative=True):
  """Weights float32 [..., S] and total optical depth sum(tau) float32 [...] (may be +inf).

  exact_derivative: alpha's derivative is exp(-tau) (`one_minus_exp_neg`); False: expm1's own,
  1 + expm1(-tau), which differs from it by float32 rounding (~6e-8 absolute). The proposal
  levels train with that one (samplers/proposal.py), as they always have: the same runs give
  the same bits."""
  # minimum (not where) so a NaN density still shows up as NaN; see MAX_DENSITY for the clamp.
  sigma = jnp.minimum(sigma.astype(jnp.float32), MAX_DENSITY)
  t = t.astype(jnp.float32)
  delta = jnp.maximum(t[..., 1:] - t[..., :-1], 0.0)  # unsorted edges give empty intervals
  tau = sigma * delta
  alpha = one_minus_exp_neg(tau) if exact_derivative else -jnp.expm1(-tau)
  optical_depth = exclusive_cumsum(tau)
  transmittance = jnp.exp(-optical_depth)  # exactly 0 behind an opaque sample
  return alpha * transmittance, optical_depth[..., -1] + tau[..., -1]


def weights(sigma, t, exact_derivative=True):
  """Compositing weights float32 [..., S] of densities sigma float32 [..., S] on the intervals
  of t float32 [..., S + 1] (`weights_and_optical_depth`'s first part; exact_derivative as
  there)."""
  return weights_and_optical_depth(sigma, t, exact_derivative)[0]


def two_part_weights(sigma, sigma_t, t):
  """NeRF-W's weights of a static and a transient field along the same intervals (eq. 10):
  both are attenuated by the transmittance of their summed densities, T_i = exp(-sum_{j<i}
  (sigma_j + sigma_t_j)·delta_j), and each is weighted by its own alpha: w_i = T_i·alpha(
  sigma_i·delta_i), w_t_i = T_i·alpha(sigma_t_i·delta_i).

  sigma, sigma_t: float [..., S] densities >= 0 (per unit of t). t: float32 [..., S + 1].
  Returns (weights, transient_weights) float32 [..., S] and the total optical depth float32
  [...] of the summed densities. With sigma_t = 0 they are `weights_and_optical_depth`'s, bit
  for bit (the same operations, tau + 0 = tau), and transient_weights are 0. Both densities are
  clamped at MAX_DENSITY, as there."""
  sigma = jnp.minimum(sigma.astype(jnp.float32), MAX_DENSITY)
  sigma_t = jnp.minimum(sigma_t.astype(jnp.float32), MAX_DENSITY)
  t = t.astype(jnp.float32)
  delta = jnp.maximum(t[..., 1:] - t[..., :-1], 0.0)  # unsorted edges give empty intervals
  tau, tau_t = sigma * delta, sigma_t * delta
  tau_sum = tau + tau_t  # finite: each term is at most MAX_DENSITY·delta
  optical_depth = exclusive_cumsum(tau_sum)
  transmittance = jnp.exp(-optical_depth)  # exactly 0 behind an opaque sample of either field
  weights = one_minus_exp_neg(tau) * transmittance
  transient_weights = one_minus_exp_neg(tau_t) * transmittance
  return weights, transient_weights, optical_depth[..., -1] + tau_sum[..., -1]
