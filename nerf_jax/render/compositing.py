"""Alpha compositing along rays: colour, depth and opacity from the quadrature's weights
(volume/quadrature.py: optical depth, alpha, transmittance, weights).

Names and axes:
  t:       float32 [..., S + 1]  sorted interval edges; sample i covers [t_i, t_{i+1}]
  delta:   float32 [..., S]      interval lengths t_{i+1} - t_i (>= 0)
  sigma:   float32 [..., S]      volume density of each sample (>= 0)
  rgb:     float32 [..., S, 3]   colour of each sample
  weights: float32 [..., S]      w_i = T_i · alpha_i, the probability the ray ends in interval i

Stability (see docs/numerics.md):
  * optical thickness tau_i = sigma_i·delta_i is summed, never multiplied: T_i = exp(-sum_{j<i}
    tau_j) underflows gracefully to exactly 0 behind an opaque sample, where cumprod(1 - alpha +
    1e-10) leaks light through it and cumprod(1 - alpha) has zero-product gradient trouble;
  * alpha_i = 1 - exp(-tau_i) and acc = 1 - exp(-sum tau) are computed with expm1 (1 - exp(-tau)
    rounds to 0 below tau = 6e-8) and given the exact derivative exp(-tau);
  * densities are clamped at quadrature.MAX_DENSITY so tau stays finite and no 0·inf appears;
  * there is no infinite last interval: the ray ends at t_S and the background takes what is left;
  * compositing is done in float32 whatever the network's dtype.
"""

import jax.numpy as jnp

from nerf_jax.backend import precision
from nerf_jax.volume import quadrature

# A ray with opacity acc <= EMPTY_ACC counts as empty; its depth is then `far` (t_S).
EMPTY_ACC = 1e-10

def composite(rgb, sigma, t, background=None):
  """Composite samples along rays into pixel colour, depth and opacity.

  rgb: float [..., S, 3], sample colours. sigma: float [..., S], densities >= 0.
  t: float32 [..., S + 1], sorted interval edges. background: None (black) or float32
  broadcastable to [..., 3].
  Returns a dict:
    rgb: float32 [..., 3], composited colour over the background;
    depth: float32 [...] in [t_0, t_S], expected termination distance E[t | the ray ends in
      [t_0, t_S]] (z-depth), and t_S (far) for an empty ray (acc <= EMPTY_ACC);
    acc: float32 [...], opacity 1 - exp(-sum tau) in [0, 1];
    weights: float32 [..., S], >= 0; their sum equals acc up to float32 rounding (~1e-7·S).
  """
  t = t.astype(jnp.float32)
  weights, total = quadrature.weights_and_optical_depth(sigma, t)
  # From the total rather than sum(weights): one rounding instead of S, and the gradient
  # d acc / d sigma_i = delta_i·exp(-total) comes out exactly (sum(weights) gives it only up to
  # an absolute error of ~2e-7·delta_i, which swamps it once the ray is opaque).
  acc = quadrature.one_minus_exp_neg(total)
  colour = precision.einsum("...s,...sc->...c", weights, rgb.astype(jnp.float32))
  if background is not None:
    # Remaining transmittance; acc <= 1 by construction, max(0, .) guards any future change.
    bg_weight = jnp.maximum(0.0, 1.0 - acc)
    colour = colour + bg_weight[..., None] * jnp.asarray(background, jnp.float32)
  mids = 0.5 * (t[..., 1:] + t[..., :-1])
  depth = _safe_expected_depth(weights, acc, mids, t[..., -1])
  # Rounding can put the weighted mean a hair outside the edges.
  depth = jnp.clip(depth, t[..., 0], t[..., -1])
  return {"rgb": colour, "depth": depth, "acc": acc, "weights": weights}


def _safe_expected_depth(weights, acc, mids, far):
  """sum(w·t)/sum(w) with the 'double where' so value and gradient stay finite for acc -> 0.

  weights, mids: float32 [..., S]. acc: float32 [...], the opacity that decides emptiness (as in
  renderer.py). far: float32 [...], the depth of an empty ray.
  Normalising by sum(w) (not acc) makes the depth a convex combination of the midpoints; sum(w)
  equals acc to float32 rounding (relative ~1e-7·S), so it is > 0 wherever acc > EMPTY_ACC. The
  inner where gives the division a safe denominator on the branch that is discarded; without it
  the gradient of the discarded branch is 0·inf = NaN.
  """
  nonempty = acc > EMPTY_ACC
  safe_wsum = jnp.where(nonempty, jnp.sum(weights, axis=-1), 1.0)
  return jnp.where(nonempty, jnp.sum(weights * mids, axis=-1) / safe_wsum, far)


def disparity(depth):
  """Inverse depth, float32 [...] from depth float32 [...] > 0 (finite: depth >= near > 0)."""
  return 1.0 / jnp.maximum(depth, 1e-10)


def composite_with_transient(rgb, sigma, rgb_t, sigma_t, beta, t, background=None, *,
                             beta_min):
  """`composite` of a static and a transient field together (NeRF-W, eq. 10), with the
  transient field's uncertainty rendered by its own weights.

  rgb, sigma: the static field's float [..., S, 3] and [..., S] (densities >= 0). rgb_t,
  sigma_t, beta: the transient field's colour float [..., S, 3], density float [..., S] >= 0 and
  uncertainty float [..., S] >= 0. t: float32 [..., S + 1]. background: as in `composite`.
  beta_min: float > 0 (the head's, TransientField.beta_min), added to the rendered uncertainty.
  Returns `composite`'s dict, where rgb is sum_i T_i·(alpha_i·c_i + alpha_t_i·c_t_i) (+ the
  background by the transmittance left, exp(-sum of both optical depths)), acc is 1 minus that
  transmittance, depth is that of both weights and weights the static ones; and besides them
  transient_weights float32 [..., S] and beta float32 [...] = sum_i w_t_i·beta_i + beta_min.
  With sigma_t = 0 rgb, depth, acc and weights equal `composite`'s bit for bit.
  """
  t = t.astype(jnp.float32)
  weights, weights_t, total = quadrature.two_part_weights(sigma, sigma_t, t)
  acc = quadrature.one_minus_exp_neg(total)
  colour = precision.einsum("...s,...sc->...c", weights, rgb.astype(jnp.float32))
  colour = colour + precision.einsum("...s,...sc->...c", weights_t, rgb_t.astype(jnp.float32))
  if background is not None:
    bg_weight = jnp.maximum(0.0, 1.0 - acc)  # as in `composite`
    colour = colour + bg_weight[..., None] * jnp.asarray(background, jnp.float32)
  mids = 0.5 * (t[..., 1:] + t[..., :-1])
  depth = _safe_expected_depth(weights + weights_t, acc, mids, t[..., -1])
  depth = jnp.clip(depth, t[..., 0], t[..., -1])
  rendered_beta = jnp.sum(weights_t * beta.astype(jnp.float32), axis=-1) + beta_min
  return {"rgb": colour, "depth": depth, "acc": acc, "weights": weights,
          "transient_weights": weights_t, "beta": rendered_beta}
