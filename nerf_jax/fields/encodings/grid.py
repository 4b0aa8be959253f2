"""Dense feature grids with trilinear interpolation (the fast encoding, config name 'grid';
settings config.model.grid), and what every lattice encoding shares: the box it covers
(`Space`) and the coarse-to-fine window over its levels.

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

import dataclasses
from typing import Sequence

import jax.numpy as jnp
import numpy as np

from nerf_jax.backend import components, draws
from nerf_jax.fields import registry
from nerf_jax.fields.encodings import posenc, scale_weights


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


def weigh_levels(h, level_weights):
  """Features float [..., L·F] of L equal-width levels, level l scaled by level_weights[l]
  (float32 [L]; None = unchanged): BARF's coarse-to-fine window over a lattice's levels."""
  if level_weights is None:
    return h
  levels = level_weights.shape[0]
  scaled = h.reshape(*h.shape[:-1], levels, -1) * level_weights[:, None].astype(h.dtype)
  return scaled.reshape(h.shape)


def antialiased(level_features, std, cells):
  """Zip-NeRF's features of a frustum from those of its M multisamples: each level's features
  weighted by scale_weights.level_weights of the sample's scale against the level's cell size,
  then averaged over the M (6, or 1: the frustum's mean).

  level_features: float [..., M, L, F]. std: float32 [..., M], each multisample's scale.
  cells: float32 [L], each level's cell size in std's units. Returns float [..., L·F].
  """
  weights = scale_weights.level_weights(std, cells).astype(level_features.dtype)  # [..., M, L]
  features = jnp.mean(level_features * weights[..., None], axis=-3)  # [..., L, F]
  return features.reshape(*features.shape[:-2], -1)


def level_window(bands, stages):
  """float32 [stages + 1] weights of a lattice's levels with `bands` open: the coarsest always
  open, the others opening as posenc.coarse_to_fine_weights opens bands."""
  rest = posenc.coarse_to_fine_weights(bands, stages)
  return jnp.concatenate([jnp.ones((1,), jnp.float32), rest])


@dataclasses.dataclass(frozen=True)
class Space:
  """The box a lattice covers: the cube [-bound, bound]^3, or `box` (min x, y, z, max x, y, z)
  when set, in cells whose x, y, z sides are in the ratio `cell_aspect`."""
  bound: float = 1.5
  box: Sequence[float] = ()
  cell_aspect: Sequence[float] = (1.0, 1.0, 1.0)

  @classmethod
  def of(cls, shared):
    """The Space of protocol.NetworkSettings `shared`."""
    return cls(shared.grid_bound, tuple(shared.grid_box), tuple(shared.grid_cell_aspect))

  def unit(self, points):
    """World positions float32 [..., 3] in the box's unit cube, float32 [..., 3]."""
    points = points.astype(jnp.float32)
    if not self.box:
      return to_unit_cube(points, self.bound)
    return to_unit_box(points, (self.box[:3], self.box[3:]))

  def shape(self, resolution):
    """Lattice points per axis of a level with `resolution` along the axis with most cells."""
    box = (self.box[:3], self.box[3:]) if self.box else ((-self.bound,) * 3, (self.bound,) * 3)
    return axis_resolutions(resolution, box, self.cell_aspect)

  def inside(self, points):
    """bool [...]: whether world positions float32 [..., 3] lie inside the box."""
    return inside_box(self.unit(points))

  def cell_sizes(self, resolutions):
    """float32 [L]: each level's cell size (world units) along the axis with most cells, for
    levels of `resolutions` lattice points along it (scale_weights.cell_sizes)."""
    box = (self.box[:3], self.box[3:]) if self.box else ((-self.bound,) * 3, (self.bound,) * 3)
    sides = np.asarray(box[1], np.float64) - np.asarray(box[0], np.float64)
    axis = int(np.argmax(sides / np.asarray(self.cell_aspect, np.float64)))  # axis_resolutions'
    return scale_weights.cell_sizes(resolutions, sides[axis])


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model.grid."""
  resolutions: Sequence[int] = (32, 64, 128)  # lattice points per side of each level
  features: int = 4  # features per lattice point
  density_resolutions: Sequence[int] = ()  # density from one-channel grids; () = from the head
  density_hash_resolution: int = 0  # with density_resolutions: a hashed finer level (0 = none)
  density_hash_log2_size: int = 20  # log2 of the hashed density level's rows
  colour_hash_resolution: int = 0  # with density_resolutions: a hashed finer colour level
  colour_hash_log2_size: int = 20  # log2 of the hashed colour level's rows
  antialias: bool = False  # Zip-NeRF: 6 points per frustum, levels weighted by its scale
  multisample: bool = True  # with antialias: the 6 points (False: the frustum's mean alone)

  def __post_init__(self):
    if not self.density_resolutions and (self.density_hash_resolution
                                         or self.colour_hash_resolution):
      raise ValueError("config.model.grid.density_hash_resolution and colour_hash_resolution "
                       "add levels to the split network: they need "
                       "config.model.grid.density_resolutions")


@dataclasses.dataclass(frozen=True)
class DenseGrid:
  """Multiresolution dense feature grids over `space` (protocol.Encoding): parameters
  'grid_<resolution>' float32 [Rx, Ry, Rz, features], 1e-2·N(0, 1) at the start."""
  settings: Settings
  space: Space

  @property
  def coarse_to_fine_stages(self):
    return max(len(self.settings.resolutions) - 1, 0)

  def band_weights(self, bands):
    return level_window(bands, self.coarse_to_fine_stages)

  def features(self, module, points, weights=None, multisamples=None):
    """float32 [..., levels·features] at world positions float32 [..., 3] (clamped to the box
    outside it), level l scaled by weights[l]; the grids are `module`'s parameters.
    multisamples: None, or Zip-NeRF's (points float32 [..., M, 3], std float32 [..., M]) of
    each frustum (settings.antialias; M = 6, or 1 without multisample): their features, `antialiased`, instead of points'."""
    init = draws.normal_init(1e-2)
    grids = [module.param(f"grid_{r}", init, (*self.space.shape(r), self.settings.features))
             for r in self.settings.resolutions]
    if multisamples is None:
      return weigh_levels(multires_features(grids, self.space.unit(points)), weights)
    six, std = multisamples
    unit = self.space.unit(six)
    levels = jnp.stack([trilinear(g, unit) for g in grids], axis=-2)  # [..., M, L, F]
    cells = self.space.cell_sizes(self.settings.resolutions)
    return weigh_levels(antialiased(levels, std, cells), weights)

  def inside(self, points):
    return self.space.inside(points)

  def width(self, dim):
    del dim
    return len(self.settings.resolutions) * self.settings.features


def build(settings, shared):
  """The DenseGrid of `settings` over the space of `shared` (protocol.NetworkSettings)."""
  return DenseGrid(settings, Space.of(shared))


def lattice_signature(settings):
  """The dense levels' entries of a checkpoint signature (every lattice encoding records them:
  registry.Encoding.records_grid_section)."""
  return components.signature(settings, "grid_", exclude=_SPLIT + ("antialias", "multisample"))


_SPLIT = ("density_resolutions", "density_hash_resolution", "density_hash_log2_size",
          "colour_hash_resolution", "colour_hash_log2_size")


def signature(settings):
  """The grid encoding's entries beyond `lattice_signature`: the density grids and hashed
  levels, only when set (so checkpoints saved before they existed stay valid)."""
  entries = {"encoding": "grid"}
  if settings.antialias:  # only when on: checkpoints saved before it keep restoring
    entries["grid_antialias"] = True if settings.multisample else "scales"
  if settings.density_resolutions:
    entries["grid_density_resolutions"] = list(settings.density_resolutions)
    for part in ("density", "colour"):
      if getattr(settings, f"{part}_hash_resolution"):
        entries[f"grid_{part}_hash"] = [getattr(settings, f"{part}_hash_resolution"),
                                        getattr(settings, f"{part}_hash_log2_size")]
  return entries


def _network(settings):
  """The lattice head, or with density_resolutions the split network (networks/density_grid.py)."""
  return "density_grid" if settings.density_resolutions else "lattice"


# Lattice tables (loss.total_variation): the feature grids and the density levels, 3 spatial axes.
def _cones(settings):
  return cone_kind(settings)


def cone_kind(settings):
  """What a lattice with `settings.antialias` and `settings.multisample` reads of each frustum
  (registry.Encoding.cones): '', 'multisamples' or 'scales'."""
  if not settings.antialias:
    return ""
  return "multisamples" if settings.multisample else "scales"


ENCODING = registry.Encoding("grid", Settings, build, signature, network=_network,
                             table_axes={"grid_": 3, "density_": 3}, records_grid_section=True,
                             cones=_cones)
