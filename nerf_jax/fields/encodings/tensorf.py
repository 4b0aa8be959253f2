"""Vector–matrix factorised feature fields (TensoRF-VM, Chen et al. 2022): config name 'tensorf',
settings config.model.tensorf (`Settings`), read by the lattice head unless model.network says.

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

import dataclasses
from typing import Sequence

import jax.numpy as jnp

from nerf_jax.backend import components, draws
from nerf_jax.fields import registry
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


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model.tensorf."""
  resolutions: Sequence[int] = (128, 256)  # lattice points along the box's longest side, per level
  rank: int = 16  # components per plane-line pair (3 x rank features per level)


@dataclasses.dataclass(frozen=True)
class TensoRF:
  """Levels of vector-matrix factorised fields over `space` (protocol.Encoding). Each level is
  a TensoRF-VM field with `rank` components per mode and `resolution` lattice points along the
  box's longest side (3·rank features); the levels' features are concatenated. Parameters
  'plane_<resolution>_<mode>' and 'line_<resolution>_<mode>' start at 0.1·N(0, 1), so their
  products, the features, start at about the dense grids' 1e-2."""
  settings: Settings
  space: grid.Space

  @property
  def coarse_to_fine_stages(self):
    return max(len(self.settings.resolutions) - 1, 0)

  def band_weights(self, bands):
    return grid.level_window(bands, self.coarse_to_fine_stages)

  def features(self, module, points, weights=None):
    """float32 [..., levels·3·rank] at world positions float32 [..., 3] (clamped to the box
    outside it), level l scaled by weights[l]; the planes and lines are `module`'s parameters."""
    init = draws.normal_init(0.1)
    unit = self.space.unit(points)
    features = []
    for r in self.settings.resolutions:
      plane_shapes, line_shapes = shapes(self.space.shape(r), self.settings.rank)
      planes = [module.param(f"plane_{r}_{m}", init, s) for m, s in enumerate(plane_shapes)]
      lines = [module.param(f"line_{r}_{m}", init, s) for m, s in enumerate(line_shapes)]
      features.append(vm_features(planes, lines, unit))
    return grid.weigh_levels(jnp.concatenate(features, axis=-1), weights)

  def inside(self, points):
    return self.space.inside(points)

  def width(self, dim):
    del dim
    return len(self.settings.resolutions) * 3 * self.settings.rank


def build(settings, shared):
  """The TensoRF of `settings` over the space of `shared` (protocol.NetworkSettings)."""
  return TensoRF(settings, grid.Space.of(shared))


def signature(settings):
  """The planes' and lines' shapes."""
  return {"encoding": "tensorf", **components.signature(settings, "tensorf_")}


# Lattice tables (loss.total_variation): the planes (2 spatial axes) and lines (1).
ENCODING = registry.Encoding("tensorf", Settings, build, signature, network="lattice",
                             table_axes={"plane_": 2, "line_": 1}, records_grid_section=True)
