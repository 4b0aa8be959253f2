"""The 'tensorf' family: TensoRF's vector-matrix factorised fields (encodings/tensorf.py) and
the grid networks' tiny head (TensoRFNeRF). Settings: config.model.tensorf. Takes raw world
positions float32 [..., 3]; see network.py.
"""

import dataclasses
from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.backend import draws
from nerf_jax.fields import registry
from nerf_jax.fields.encodings import tensorf
from nerf_jax.fields.networks import heads


class TensoRFNeRF(heads.GridHead):
  """GridNeRF with vector-matrix factorised fields (tensorf.py) in place of the dense grids.

  The same inputs, outputs, head and out-of-box density as GridNeRF. Each level is a TensoRF-VM
  field with `rank` components per mode and `resolution` lattice points along the box's longest
  side (3·rank features); the levels' features are concatenated. Planes and lines start at
  0.1·N(0, 1), so their products, the features, start at about GridNeRF's 1e-2.
  """
  resolutions: Sequence[int] = (128, 256)
  rank: int = 16
  bound: float = 1.5
  box: Sequence[float] = ()  # as GridNeRF's

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None):
    init = draws.normal_init(0.1)
    unit = self._unit(points.astype(jnp.float32))
    features = []
    for r in self.resolutions:
      plane_shapes, line_shapes = tensorf.shapes(self._shape(r), self.rank)
      planes = [self.param(f"plane_{r}_{m}", init, s) for m, s in enumerate(plane_shapes)]
      lines = [self.param(f"line_{r}_{m}", init, s) for m, s in enumerate(line_shapes)]
      features.append(tensorf.vm_features(planes, lines, unit))
    h = heads.weigh_levels(jnp.concatenate(features, axis=-1), level_weights)
    return self._head(h.astype(jnp.dtype(self.dtype)), unit, dir_features, image)



@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model.tensorf."""
  resolutions: Sequence[int] = (128, 256)  # lattice points along the box's longest side, per level
  rank: int = 16  # components per plane-line pair (3 x rank features per level)


def build(settings, shared):
  """The TensoRFNeRF of `settings` (network.NetworkSettings: shared)."""
  return TensoRFNeRF(resolutions=tuple(settings.resolutions), rank=settings.rank,
                     **shared.space, **shared.head)


def signature(settings):
  """The planes' and lines' shapes."""
  return {"encoding": "tensorf", "tensorf_resolutions": list(settings.resolutions),
          "tensorf_rank": settings.rank}


# Lattice tables (train.tv_weight): the planes (2 spatial axes) and lines (1).
ENCODING = registry.Encoding("tensorf", Settings, build, signature,
                             table_axes={"plane_": 2, "line_": 1}, records_grid_section=True)
