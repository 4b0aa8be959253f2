"""Vector–matrix factorised feature fields (TensoRF-VM, Chen et al. 2022).

A 3-D feature field is a sum of three modes; mode m pairs a plane over two axes with a line
along the third, and its C components multiply point by point:
  features(x, y, z) = [P_xy(x, y) * L_z(z),  P_xz(x, z) * L_y(y),  P_yz(y, z) * L_x(x)]
Each read is bilinear on a plane (4 corners) and linear on a line (2 corners): 18 gathers of C
floats per point whatever the resolution, and the tables hold 3·R²·C + 3·R·C floats instead of
a dense grid's R³·F, so the optimiser's dense update stays small at fine resolutions. Its
backward pass still scatter-adds 18 rows of C floats per point: on a 2-core CPU it costs more
per sample than the dense levels (docs/quality_per_second.md).

Names:
  planes: 3 arrays float32 [Ra, Rb, C]  mode m's plane over axes MODES[m][0] (Ra lattice points
                                        along the first, Rb along the second)
  lines:  3 arrays float32 [Rc, C]      mode m's line along axis MODES[m][1]
  unit:   float32 [..., 3]              positions in [0, 1]^3 (grid.to_unit_cube / to_unit_box)
"""

import jax.numpy as jnp

from nerf_jax.fields.encodings import grid

# (the plane's two axes, the line's axis) of each mode
MODES = (((0, 1), 2), ((0, 2), 1), ((1, 2), 0))


def linear(line, coord):
  """Linear interpolation of line float32 [R, C] at coord float32 [...] in [0, 1].
  Returns float32 [..., C]."""
  lower, frac = grid.lower_corner(coord, line.shape[0])
  frac = frac[..., None]
  return (1.0 - frac) * line[lower] + frac * line[lower + 1]


def bilinear(plane, u, v):
  """Bilinear interpolation of plane float32 [Ra, Rb, C] at u, v float32 [...] in [0, 1]
  (u along its first axis). Returns float32 [..., C]."""
  rows, cols = plane.shape[:2]
  iu, fu = grid.lower_corner(u, rows)
  iv, fv = grid.lower_corner(v, cols)
  fu, fv = fu[..., None], fv[..., None]
  flat = plane.reshape(rows * cols, plane.shape[-1])
  at = lambda du, dv: flat[(iu + du) * cols + iv + dv]
  return ((1.0 - fu) * ((1.0 - fv) * at(0, 0) + fv * at(0, 1))
          + fu * ((1.0 - fv) * at(1, 0) + fv * at(1, 1)))


def vm_features(planes, lines, unit):
  """The three modes' plane × line products at unit float32 [..., 3], concatenated:
  float32 [..., 3C] (positions outside [0, 1]^3 are clamped to the box; callers mask them)."""
  out = []
  for plane, line, ((a, b), c) in zip(planes, lines, MODES):
    out.append(bilinear(plane, unit[..., a], unit[..., b]) * linear(line, unit[..., c]))
  return jnp.concatenate(out, axis=-1)


def shapes(axis_points, rank):
  """(plane shapes, line shapes) of the three modes for lattice points per axis (3 ints)."""
  planes = [(axis_points[a], axis_points[b], rank) for (a, b), _ in MODES]
  lines = [(axis_points[c], rank) for _, c in MODES]
  return planes, lines
