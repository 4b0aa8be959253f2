"""The 'hash' family: instant-ngp's multiresolution hash grid (encodings/hashgrid.py) and the
grid networks' tiny head (HashNeRF). Settings: config.model.hash. Takes raw world positions
float32 [..., 3]; see network.py.
"""

import dataclasses
from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.backend import draws
from nerf_jax.fields import registry
from nerf_jax.fields.encodings import hashgrid
from nerf_jax.fields.networks import heads


class HashNeRF(heads.GridHead):
  """GridNeRF with a multiresolution hash grid (hashgrid.py) in place of the dense grids.

  The same inputs, outputs, head and out-of-box density as GridNeRF; the table holds the
  `levels` levels' rows, initialised uniform in ±1e-4 as in instant-ngp (the MLP starts from a
  nearly constant field, and no level dominates before training).
  gather_dtype: dtype of the gathered corner rows (the table stays float32, see hashgrid.encode).
  """
  levels: int = 16
  log2_size: int = 19
  features: int = 2
  base_resolution: int = 16
  max_resolution: int = 2048
  gather_dtype: str = "float32"
  bound: float = 1.5
  box: Sequence[float] = ()  # as GridNeRF's

  @property
  def num_levels(self):
    return self.levels

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None):
    resolutions = hashgrid.level_resolutions(self.levels, self.base_resolution,
                                             self.max_resolution)
    rows = sum(hashgrid.level_rows(resolutions, self.log2_size))
    init = lambda key, shape: draws.uniform(key, shape, jnp.float32, -1e-4, 1e-4)
    table = self.param("hash_table", init, (rows, self.features))
    unit = self._unit(points.astype(jnp.float32))
    h = hashgrid.encode(table, unit, resolutions, self.log2_size, self.gather_dtype)
    h = heads.weigh_levels(h, level_weights)
    return self._head(h.astype(jnp.dtype(self.dtype)), unit, dir_features, image)



@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model.hash."""
  levels: int = 16  # resolution levels
  log2_size: int = 19  # log2 of the rows of each level's table
  features: int = 2  # features per row
  base_resolution: int = 16  # lattice points per side of the coarsest level
  max_resolution: int = 2048  # lattice points per side of the finest level
  gather_dtype: str = "float32"  # dtype of the gathered rows (the table stays float32)


def build(settings, shared):
  """The HashNeRF of `settings` (network.NetworkSettings: shared)."""
  return HashNeRF(**dataclasses.asdict(settings), **shared.space, **shared.head)


def signature(settings):
  """The table's shape and the meaning of its rows (the gathered dtype changes neither)."""
  entries = {f"hash_{k}": v for k, v in dataclasses.asdict(settings).items()
             if k != "gather_dtype"}
  return {"encoding": "hash", **entries}


ENCODING = registry.Encoding("hash", Settings, build, signature, records_grid_section=True)
