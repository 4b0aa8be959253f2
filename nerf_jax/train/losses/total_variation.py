"""The total variation of the field's lattice tables as a term (config.loss.total_variation;
the per-table sum is train/regularizers.total_variation)."""

import dataclasses
from typing import Any, ClassVar

from nerf_jax.fields import registry
from nerf_jax.train import losses, regularizers


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.loss.total_variation."""
  weight: float = 0.0  # grid encodings: total variation of the lattice tables (0 = off)

  def __post_init__(self):
    losses.check_weight(self.weight, "total_variation", "0.01, TensoRF's on LLFF")


@dataclasses.dataclass(frozen=True)
class TotalVariation:
  """Smooth lattice tables where few rays constrain them (LLFF): `weight` times the total
  variation of every lattice table of the field's encoding family (table_axes: (parameter-name
  prefix, spatial axes) pairs, registry.Encoding.table_axes), summed. No stats."""
  name: ClassVar[str] = "total_variation"
  weight: float
  table_axes: Any = ()

  def __call__(self, inputs):
    tables = registry.lattice_tables(inputs.params, dict(self.table_axes))
    return self.weight * sum(regularizers.total_variation(table, axes)
                             for table, axes in tables), {}


def build(settings, context):
  """The term on the field's tables (context.table_axes); None at weight 0."""
  if settings.weight <= 0:
    return None
  return TotalVariation(settings.weight, context.table_axes)


LOSS = losses.Loss(TotalVariation.name, Settings, build)
