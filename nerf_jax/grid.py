"""Dense feature grids with trilinear interpolation (the fast encoding).

A grid covers the scene box [-bound, bound]^3. Names:
  grid:   float32 [R, R, R, F]  features at the R^3 lattice points (corners of R-1 cells)
  points: float32 [..., 3]      world positions
  unit:   float32 [..., 3]      positions mapped to [0, 1]^3 (0 = -bound, 1 = +bound)
Interpolation gathers the 8 lattice points around each position; its gradient is a scatter-add
into the grid, so the cost per sample is independent of the grid size.
"""

import jax.numpy as jnp


def to_unit_cube(points, bound):
  """World positions float32 [..., 3] -> float32 [..., 3] in [0, 1] inside the box."""
  return (points / bound + 1.0) * 0.5


def inside_box(unit):
  """bool [...]: whether unit-cube positions float32 [..., 3] lie inside [0, 1]^3."""
  return jnp.all((unit >= 0.0) & (unit <= 1.0), axis=-1)


def trilinear(grid, unit):
  """Trilinear interpolation of grid: float32 [R, R, R, F] at unit: float32 [..., 3].

  Positions outside [0, 1]^3 are clamped to the box surface (callers mask them out).
  Returns float32 [..., F].
  """
  res = grid.shape[0]
  x = jnp.clip(unit, 0.0, 1.0) * (res - 1)
  # floor clamped to res - 2 so the upper corner index stays in range at x = res - 1.
  lower = jnp.clip(jnp.floor(x), 0, res - 2).astype(jnp.int32)
  frac = x - lower  # in [0, 1]
  flat = grid.reshape(-1, grid.shape[-1])
  out = 0.0
  for corner in range(8):
    offset = jnp.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1], jnp.int32)
    idx = lower + offset
    w = jnp.prod(jnp.where(offset == 1, frac, 1.0 - frac), axis=-1, keepdims=True)
    flat_idx = (idx[..., 0] * res + idx[..., 1]) * res + idx[..., 2]
    out = out + w * flat[flat_idx]
  return out


def multires_features(grids, unit):
  """Concatenated trilinear features of several grids: float32 [..., sum of F]."""
  return jnp.concatenate([trilinear(g, unit) for g in grids], axis=-1)
