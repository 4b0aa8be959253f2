"""Regularisers: losses on a ray's weights that keep empty space empty (no floaters), and the
total variation that keeps a feature table smooth where few rays constrain it.

The distortion loss of mip-NeRF 360 (Barron et al. 2022, eq. 15) is small when a ray's weight
sits in one short interval and large when it is spread along the ray (a cloud of faint
floaters in front of a surface, or a smeared surface). For weights w_i on intervals
[t_i, t_{i+1}] with midpoints m_i:

  L = sum_ij w_i w_j |m_i - m_j|  +  1/3 sum_i w_i^2 (t_{i+1} - t_i)

The double sum is computed in O(S) from prefix sums (midpoints are sorted), not O(S^2).
"""

import jax.numpy as jnp


def distortion(t, weights):
  """The distortion loss per ray: float32 [...].

  t: float32 [..., S + 1], sorted interval edges. weights: float32 [..., S], >= 0 (zero-width
  or zero-weight intervals, such as the gaps of occupancy sampling, contribute nothing).
  """
  mids = 0.5 * (t[..., 1:] + t[..., :-1])
  # sum_ij w_i w_j |m_i - m_j| = 2 sum_i w_i (m_i W_<i - (wm)_<i) for sorted m: each pair
  # once, later midpoint first. The prefix sums are <= max(m)·sum(w), so for t of a few scene
  # units the difference keeps float32's relative precision of those sums (~1e-7 · max t).
  w_before = jnp.cumsum(weights, axis=-1) - weights
  wm_before = jnp.cumsum(weights * mids, axis=-1) - weights * mids
  between = 2.0 * jnp.sum(weights * (mids * w_before - wm_before), axis=-1)
  within = jnp.sum(weights ** 2 * (t[..., 1:] - t[..., :-1]), axis=-1) / 3.0
  return between + within


def total_variation(table, spatial_axes):
  """Mean squared difference between neighbouring lattice points of table float32
  [R_1, ..., R_k, C] along its first `spatial_axes` (k) axes, summed over those axes: float32 [].

  DVGO and TensoRF use it on forward-facing captures, where a cell seen by few cameras would
  otherwise take any value that fits them. Axes with a single lattice point contribute 0.
  """
  total = 0.0
  for axis in range(spatial_axes):
    if table.shape[axis] > 1:
      total = total + jnp.mean(jnp.square(jnp.diff(table, axis=axis)))
  return total
