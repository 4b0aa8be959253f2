"""The 'grid' family: multiresolution dense feature grids over the scene box and a tiny head
(GridNeRF), or, with density_resolutions, density read straight from grids of its own
(DensityGridNeRF, DVGO's recipe). Settings: config.model.grid.

Both take raw world positions float32 [..., 3] (the grids are the encoding); see network.py.
"""

import dataclasses
from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.backend import draws
from nerf_jax.fields import registry
from nerf_jax.fields.encodings import grid, hashgrid
from nerf_jax.fields.networks import heads


class GridNeRF(heads.GridHead):
  """The fast field: multiresolution dense feature grids over the scene box + a tiny MLP.

  Takes raw world positions `points: float32 [..., 3]` (no positional encoding: the grids are
  the encoding) and optionally encoded directions. Density and a feature come from one hidden
  layer over the concatenated grid features; colour from the feature (and direction).
  Positions outside the box get raw density -1e5, which every density activation maps to 0
  with a zero gradient (relu, softplus and exp all underflow to exactly 0 there).
  level_weights (GridNeRF, HashNeRF, TensoRFNeRF): float32 [num_levels] or None, each level's
  features scaled by its weight (`weigh_levels`: pose refinement's coarse to fine).
  """
  resolutions: Sequence[int] = (32, 64, 128)
  features: int = 4
  bound: float = 1.5
  box: Sequence[float] = ()  # (min x, y, z, max x, y, z) of a tighter box; () = the bound's cube

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None):
    init = draws.normal_init(1e-2)
    grids = [self.param(f"grid_{r}", init, (*self._shape(r), self.features))
             for r in self.resolutions]
    unit = self._unit(points.astype(jnp.float32))
    h = heads.weigh_levels(grid.multires_features(grids, unit), level_weights)
    return self._head(h.astype(jnp.dtype(self.dtype)), unit, dir_features, image)


class DensityGridNeRF(heads.GridHead):
  """GridNeRF with density read straight from grids of its own (DVGO's recipe): the raw density
  is interpolated, then activated (by the Field), so it stays sharp inside a cell; it is the sum
  of one-channel grids at several resolutions, so coarse shapes form in few steps and fine ones
  on top. Colour comes from the feature grids and the tiny MLP as in GridNeRF.

  The two halves can be evaluated alone (`part`): the density of every sample is a single
  trilinear read, and the renderer computes colour only where the weights say it matters
  (renderer.RayRenderer.colour_fraction). The density grid starts at raw INITIAL_RAW_DENSITY
  everywhere: a faint haze (DVGO's low initial opacity), so no early floaters block the rays,
  yet dense enough that the colour MLP's first gradients come from the surfaces.
  part: 'all' -> (rgb, raw_sigma); 'density' -> raw_sigma; 'colour' -> rgb.
  """
  resolutions: Sequence[int] = (32, 64, 128)
  features: int = 4
  bound: float = 1.5
  box: Sequence[float] = ()  # as GridNeRF's
  density_resolutions: Sequence[int] = (32, 64, 128)  # lattice points per side of each level
  density_hash_resolution: int = 0  # a finer, hashed density level: points per side (0 = none)
  density_hash_log2_size: int = 20  # log2 of its table's rows
  colour_hash_resolution: int = 0  # a finer, hashed colour feature level: points per side
  colour_hash_log2_size: int = 20  # log2 of its table's rows

  def _raw_density(self, unit):
    """Raw density float32 [...] at unit-box positions float32 [..., 3]: the sum of the dense
    levels and, if set, the hashed level (instant-ngp's hash: its rows cost memory and Adam's
    update in proportion to 2^log2_size, not to its resolution cubed)."""
    hashed = bool(self.density_hash_resolution)
    start = INITIAL_RAW_DENSITY / DENSITY_GAIN / (len(self.density_resolutions) + hashed)
    levels = [self.param(f"density_{r}", nn.initializers.constant(start), (*self._shape(r), 1))
              for r in self.density_resolutions]
    raw = sum(grid.trilinear(g, unit)[..., 0] for g in levels)
    if hashed:
      raw = raw + self._hashed_level("hashed_density", nn.initializers.constant(start), 1, unit,
                                     self.density_hash_resolution,
                                     self.density_hash_log2_size)[..., 0]
    return DENSITY_GAIN * raw

  def _hashed_level(self, name, init, features, unit, resolution, log2_size):
    """Features float32 [..., features] of a one-level hash grid (hashgrid.py) of `resolution`
    points per side in 2^log2_size rows (fewer if its lattice fits), the parameter `name`."""
    rows = hashgrid.level_rows((resolution,), log2_size)[0]
    table = self.param(name, init, (rows, features))
    return hashgrid.encode(table, unit, (resolution,), log2_size)

  @nn.compact
  def __call__(self, points, dir_features=None, part="all"):
    unit = self._unit(points.astype(jnp.float32))
    raw_sigma = rgb = None
    if part in ("all", "density"):
      raw = self._raw_density(unit)
      raw_sigma = jnp.where(grid.inside_box(unit), raw, -1e5)
    if part in ("all", "colour"):
      init = draws.normal_init(1e-2)
      grids = [self.param(f"grid_{r}", init, (*self._shape(r), self.features))
               for r in self.resolutions]
      h = grid.multires_features(grids, unit)
      if self.colour_hash_resolution:  # read only by the samples that get colour
        fine = self._hashed_level("hashed_colour", init, self.features, unit,
                                  self.colour_hash_resolution, self.colour_hash_log2_size)
        h = jnp.concatenate([h, fine], axis=-1)
      h = nn.relu(heads.dense(self, self.hidden, "hidden")(h.astype(jnp.dtype(self.dtype))))
      if self.view_dependent:
        h = jnp.concatenate([h, dir_features.astype(h.dtype)], axis=-1)
        h = heads.colour_layers(self, h)
      rgb = nn.sigmoid(heads.dense(self, 3, "rgb")(h).astype(jnp.float32))
    return {"all": (rgb, raw_sigma), "density": raw_sigma, "colour": rgb}[part]


  @property
  def num_levels(self):
    """0: its density grids take no coarse-to-fine window (pose refinement opens none)."""
    return 0

  @property
  def splits_density(self):
    return True


# Raw density at start: exp(-2) = 0.14 per scene unit (exp activation; the shifted softplus of
# activations.py gives softplus(-2 - 1) = 0.05), a faint haze (~1/3 opacity across a 3-unit box).
# Not fainter: at -5 (0.7% opacity) the colour's gradient in the first steps is a tiny, one-signed
# pull of the random training backgrounds against the object, which Adam's normalised steps turn
# into full steps; on the built-in `detail` every colour went to black (the sigmoid's flat end)
# in 20 steps and stayed there (18.2 dB at 400 steps; 24.1 at -2; docs/quality_per_second.md).
INITIAL_RAW_DENSITY = -2.0
# The grid stores raw density / DENSITY_GAIN: Adam's steps, about lr in size whatever the
# gradient, move raw density DENSITY_GAIN times faster than the features (DVGO trains its density
# grid with a 10x larger learning rate), so a surface forms in tens of steps, not hundreds.
DENSITY_GAIN = 10.0


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


def build(settings, shared):
  """GridNeRF, or DensityGridNeRF with density_resolutions (network.NetworkSettings: shared)."""
  s = settings
  common = dict(resolutions=tuple(s.resolutions), features=s.features, **shared.space,
                **shared.head)
  if not s.density_resolutions:
    if s.density_hash_resolution or s.colour_hash_resolution:
      raise ValueError("config.model.grid.density_hash_resolution and colour_hash_resolution "
                       "add levels to the split network: they need "
                       "config.model.grid.density_resolutions")
    return GridNeRF(**common)
  if shared.density_activation == "relu":
    raise ValueError("config.model.grid.density_resolutions needs "
                     "config.model.density_activation 'softplus' or 'exp': the density "
                     "grid starts below zero, where relu has no gradient")
  if shared.appearance_dims:
    raise ValueError("config.model.grid.density_resolutions does not take appearance codes "
                     "yet: set config.model.appearance_dims=0 or density_resolutions=()")
  return DensityGridNeRF(density_resolutions=tuple(s.density_resolutions),
                         density_hash_resolution=s.density_hash_resolution,
                         density_hash_log2_size=s.density_hash_log2_size,
                         colour_hash_resolution=s.colour_hash_resolution,
                         colour_hash_log2_size=s.colour_hash_log2_size, **common)


def lattice_signature(settings):
  """The dense levels' entries of a checkpoint signature (every grid-type family records them:
  registry.Encoding.records_grid_section)."""
  return {"grid_resolutions": list(settings.resolutions), "grid_features": settings.features}


def signature(settings):
  """The grid family's checkpoint entries beyond `lattice_signature`: the density grids and
  hashed levels, only when set (so checkpoints saved before they existed stay valid)."""
  entries = {"encoding": "grid"}
  if settings.density_resolutions:
    entries["grid_density_resolutions"] = list(settings.density_resolutions)
    for part in ("density", "colour"):
      if getattr(settings, f"{part}_hash_resolution"):
        entries[f"grid_{part}_hash"] = [getattr(settings, f"{part}_hash_resolution"),
                                        getattr(settings, f"{part}_hash_log2_size")]
  return entries


# Lattice tables (train.tv_weight): the feature grids and the density levels, 3 spatial axes.
ENCODING = registry.Encoding("grid", Settings, build, signature,
                             table_axes={"grid_": 3, "density_": 3}, records_grid_section=True)
