"""The parts the built-in networks share (Flax): Dense layers at the network's precision, the
per-image appearance codes, and the grid networks' tiny head (`GridHead`).

Grid heads take grid features float [..., F] at unit-box positions float32 [..., 3] (and encoded
directions) and give (rgb float32 [..., 3] in (0, 1), raw_sigma float32 [...]); see network.py
for the calling convention every network follows.
"""

from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.backend import precision
from nerf_jax.fields.encodings import grid


def appearance_codes(module, image, shape):
  """Per-training-image appearance codes (GLO, as NeRF-W and nerfacto): `module`'s parameter
  'appearance', a table float32 [appearance_images, appearance_dims] (zeros at the start).
  Returns codes [*shape[:-1], dims] for rays' images int32 [...] (shape = the features'
  [..., S, F]: each ray's code goes to all its samples), or the mean code for image None.
  A code conditions colour only, never density."""
  table = module.param("appearance", nn.initializers.zeros,
                       (module.appearance_images, module.appearance_dims))
  code = jnp.mean(table, axis=0) if image is None else table[image][..., None, :]
  return jnp.broadcast_to(code, (*shape[:-1], module.appearance_dims))


def colour_layers(network, h):
  """The colour branch after the direction (and appearance code) joined h float [..., C]:
  `network.view_depth` ReLU layers of `view_width`, named 'view', 'view_1', ... (the first
  keeps the name single-layer checkpoints have always used)."""
  if network.view_depth < 1:
    raise ValueError(f"config.model.view_depth must be >= 1, got {network.view_depth}")
  for i in range(network.view_depth):
    h = nn.relu(dense(network, network.view_width, f"view_{i}" if i else "view")(h))
  return h


def dense(network, features, name):
  """A Dense layer of `network` (inside its compact call): float32 parameters, the network's
  matmul dtype and float32 matmul precision (its `dtype` and `matmul_precision` fields)."""
  return nn.Dense(features, dtype=jnp.dtype(network.dtype), param_dtype=jnp.float32, name=name,
                  precision=precision.network_precision(network.matmul_precision))



class GridHead(nn.Module):
  """The tiny MLP of the grid fields: grid features float [..., F] at unit-cube positions
  float32 [..., 3] (and encoded directions) -> (rgb float32 [..., 3], raw_sigma float32 [...])."""
  hidden: int = 64
  view_dependent: bool = False
  view_width: int = 32
  view_depth: int = 1
  dtype: str = "float32"
  appearance_images: int = 1
  appearance_dims: int = 0
  cell_aspect: Sequence[float] = (1.0, 1.0, 1.0)  # relative x, y, z sides of a lattice cell
  matmul_precision: str = "default"  # precision.NETWORK_PRECISIONS: 'default', 'high', 'highest'

  def _unit(self, points):
    """Positions float32 [..., 3] in the grids' unit cube: of `box` if set, else of the cube."""
    if not self.box:
      return grid.to_unit_cube(points, self.bound)
    return grid.to_unit_box(points, (self.box[:3], self.box[3:]))

  def _shape(self, resolution):
    """Lattice points per axis of a level with `resolution` along the axis with most cells."""
    box = (self.box[:3], self.box[3:]) if self.box else ((-self.bound,) * 3, (self.bound,) * 3)
    return grid.axis_resolutions(resolution, box, self.cell_aspect)

  def _head(self, h, unit, dir_features, image=None):
    """Density and a feature from one hidden layer, colour from the feature (and direction,
    and appearance code)."""
    h = nn.relu(dense(self, self.hidden, "hidden")(h))
    raw_sigma = dense(self, 1, "sigma")(h)[..., 0].astype(jnp.float32)
    raw_sigma = jnp.where(grid.inside_box(unit), raw_sigma, -1e5)
    extra = [dir_features] if self.view_dependent else []
    if self.appearance_dims:  # colour only: the code joins h after density is taken from it
      extra.append(appearance_codes(self, image, h.shape))
    if extra:
      h = jnp.concatenate([h, *(e.astype(h.dtype) for e in extra)], axis=-1)
    if self.view_dependent:
      h = colour_layers(self, h)
    rgb = dense(self, 3, "rgb")(h).astype(jnp.float32)
    return nn.sigmoid(rgb), raw_sigma

  @property
  def num_levels(self):
    """Resolution levels of the encoding, coarsest first (their features are concatenated)."""
    return len(self.resolutions)


  @property
  def splits_density(self):
    """Density and colour come from one head (network.Network)."""
    return False


def weigh_levels(h, level_weights):
  """Features float [..., L·F] of L equal-width levels, level l scaled by level_weights[l]
  (float32 [L]; None = unchanged): BARF's coarse-to-fine window over a grid's levels."""
  if level_weights is None:
    return h
  levels = level_weights.shape[0]
  scaled = h.reshape(*h.shape[:-1], levels, -1) * level_weights[:, None].astype(h.dtype)
  return scaled.reshape(h.shape)
