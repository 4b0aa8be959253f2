"""Dense feature grids with trilinear interpolation (the fast encoding).

A grid covers a box: the scene box [-bound, bound]^3, or a tighter one (min and max corners, e.g.
the visual hull's, visual_hull.py) with as many lattice points per side as keep its cells cubic
(`axis_resolutions`). Names:
  grid:   float32 [Rx, Ry, Rz, F]  features at the lattice points (corners of (Rx-1)(Ry-1)(Rz-1)
                                   cells)
  points: float32 [..., 3]         world positions
  unit:   float32 [..., 3]         positions mapped to [0, 1]^3 (0 = the box's min, 1 = its max)
Interpolation gathers the 8 lattice points around each position; its gradient is a scatter-add
into the grid, so the cost per sample is independent of the grid size.
"""

import jax.numpy as jnp
import numpy as np


def to_unit_cube(points, bound):
  """World positions float32 [..., 3] -> float32 [..., 3] in [0, 1] inside the box."""
  return (points / bound + 1.0) * 0.5


def to_unit_box(points, box):
  """World positions float32 [..., 3] -> float32 [..., 3] in [0, 1] inside `box`, a pair of
  (min, max) corners (3 floats each)."""
  low, high = jnp.asarray(box[0], jnp.float32), jnp.asarray(box[1], jnp.float32)
  return (points - low) / (high - low)


def axis_resolutions(resolution, box, cell_aspect=(1.0, 1.0, 1.0)):
  """Lattice points per axis (3 ints) of a grid over `box` ((min, max) corners) with
  `resolution` points along the side that has the most cells, and cells whose sides are in the
  ratio `cell_aspect` (x, y, z; all ones = cubic) as nearly as whole numbers allow."""
  sides = np.asarray(box[1], np.float64) - np.asarray(box[0], np.float64)
  sides = sides / np.asarray(cell_aspect, np.float64)  # in cell lengths of each axis
  cells = (resolution - 1) * sides / sides.max()
  return tuple(int(max(2, round(c) + 1)) for c in cells)


def inside_box(unit):
  """bool [...]: whether unit-cube positions float32 [..., 3] lie inside [0, 1]^3."""
  return jnp.all((unit >= 0.0) & (unit <= 1.0), axis=-1)


def lower_corner(unit, points):
  """(lower lattice index int32 [...], fraction float32 [...]) of unit float32 [...] in [0, 1]
  (clamped) on axes of `points` lattice points (int, or int32 broadcasting against unit)."""
  x = jnp.clip(unit, 0.0, 1.0) * (points - 1)
  # floor clamped to points - 2 so the upper corner index stays in range at x = points - 1.
  lower = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, points - 2)
  return lower, x - lower  # the fraction is in [0, 1]


def trilinear(grid, unit):
  """Trilinear interpolation of grid: float32 [Rx, Ry, Rz, F] at unit: float32 [..., 3].

  Positions outside [0, 1]^3 are clamped to the box surface (callers mask them out).
  Returns float32 [..., F].
  """
  lower, frac = lower_corner(unit, jnp.array(grid.shape[:3], jnp.int32))
  flat = grid.reshape(-1, grid.shape[-1])
  out = 0.0
  for corner in range(8):
    offset = jnp.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1], jnp.int32)
    idx = lower + offset
    w = jnp.prod(jnp.where(offset == 1, frac, 1.0 - frac), axis=-1, keepdims=True)
    flat_idx = (idx[..., 0] * grid.shape[1] + idx[..., 1]) * grid.shape[2] + idx[..., 2]
    out = out + w * flat[flat_idx]
  return out


def multires_features(grids, unit):
  """Concatenated trilinear features of several grids: float32 [..., sum of F]."""
  return jnp.concatenate([trilinear(g, unit) for g in grids], axis=-1)
