"""Density-only fields: the small networks a proposal sampler queries (mip-NeRF 360, nerfacto).

`HashDensity` is nerfacto's proposal network: a small multiresolution hash grid
(encodings/hash.py) and one hidden layer to a raw density, no colour and no viewing
direction. It follows the call of protocol.py so a `field.Field` wraps it (contraction, density
activation): applied to positions float32 [..., S, 3] (world or contracted) it returns
(rgb float32 [..., S, 3], raw_sigma float32 [..., S]) with rgb all zeros, which
`Field.query_density` drops (under jit no work is spent on it). `density_field(...)` builds
that Field. Their settings are the proposal sampler's (samplers/proposal.Settings, which
declares them; `LatticeSettings` names what the networks read of them).
"""

from typing import Protocol

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.backend import draws
from nerf_jax.fields import field as field_lib
from nerf_jax.fields.encodings import grid
from nerf_jax.fields.encodings import hash as hashgrid


class LatticeSettings(Protocol):
  """What a density network reads of its settings (samplers/proposal.Settings)."""
  levels: int  # lattice levels (one level: base_resolution)
  features: int  # features per lattice point (hash row)
  base_resolution: int  # coarsest lattice, points per side
  hidden: int  # units of the head's one hidden layer
  log2_size: int  # HashDensity: log2 of each level's rows


class _DensityOnly(nn.Module):
  """What both density networks share: no levels for pose refinement, nothing to split, and the
  head from features float32 [..., F] to (zero colour, raw density) (protocol.Network).
  settings (`LatticeSettings`): settings.levels lattice levels from base_resolution to
  `max_resolution` points per side (geometric), settings.features channels, over
  [-bound, bound]^3; settings.hidden units in the head's one hidden layer."""
  settings: LatticeSettings
  max_resolution: int  # this level's finest lattice
  bound: float

  coarse_to_fine_stages = 0  # never refined: nothing opens coarse to fine

  def band_weights(self, bands):
    del bands
    return None

  @property
  def splits_density(self):
    return False  # one call gives density (and no colour): nothing to split

  def _density(self, h):
    """(rgb zeros float32 [..., 3], raw_sigma float32 [...]) from features h [..., F]."""
    h = nn.relu(nn.Dense(self.settings.hidden, name="hidden")(h))
    raw_sigma = nn.Dense(1, name="sigma")(h)[..., 0]
    return jnp.zeros((*raw_sigma.shape, 3), jnp.float32), raw_sigma


class HashDensity(_DensityOnly):
  """Raw density from a hash grid over [-bound, bound]^3 and one hidden ReLU layer.

  settings' levels, log2_size, features, base_resolution and max_resolution: the hash grid's
  (hash.py). Positions outside the box are clamped onto it (as the hash grid does); a
  proposal sampler only queries inside it (the scene box, or contracted space).
  """

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None):
    del dir_features, image, level_weights  # density only, no appearance, never refined
    s = self.settings
    resolutions = hashgrid.level_resolutions(s.levels, s.base_resolution, self.max_resolution)
    rows = sum(hashgrid.level_rows(resolutions, s.log2_size))
    init = lambda key, shape: draws.uniform(key, shape, jnp.float32, -1e-4, 1e-4)
    table = self.param("hash_table", init, (rows, s.features))
    unit = grid.to_unit_cube(points.astype(jnp.float32), self.bound)
    return self._density(hashgrid.encode(table, unit, resolutions, s.log2_size))


class GridDensity(_DensityOnly):
  """`HashDensity` with dense lattices in place of the hash grid: settings.levels grids of
  settings.features channels from base_resolution to max_resolution points per side (geometric,
  as the hash grid's levels), each read by 8 one-dimensional gathers (grid.trilinear), which a
  CPU does several times faster than the hash grid's gather of [..., levels, 8] rows. Memory
  grows with the cube of max_resolution (128: 2.1M parameters per feature)."""

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None):
    del dir_features, image, level_weights
    s = self.settings
    resolutions = hashgrid.level_resolutions(s.levels, s.base_resolution, self.max_resolution)
    init = draws.normal_init(1e-2)
    # "lattice_", no encoding's table prefix: loss.total_variation leaves the proposals alone.
    grids = [self.param(f"lattice_{r}", init, (r, r, r, s.features)) for r in resolutions]
    unit = grid.to_unit_cube(points.astype(jnp.float32), self.bound)
    return self._density(grid.multires_features(grids, unit))


def density_field(network, contraction, inner_radius=1.0):
  """A Field around the density-only `network`: positions taken raw (contracted first with
  `contraction` 'l2' / 'linf' about the box of half-size `inner_radius`), density through the
  truncated exponential of nerfacto's proposal networks (activations.safe_exp)."""
  return field_lib.Field(network, density_activation="exp",
                         contraction=contraction, inner_radius=inner_radius)
