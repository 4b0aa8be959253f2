"""A prior on the cameras' corrections as a term (config.loss.pose_prior; pose refinement
only)."""

import dataclasses
from typing import ClassVar

import jax.numpy as jnp

from nerf_jax.train import losses


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.loss.pose_prior."""
  weight: float = 3.0  # pose refinement: weight of a pull of the corrections toward none

  def __post_init__(self):
    losses.check_weight(self.weight, "pose_prior", "3")


@dataclasses.dataclass(frozen=True)
class PosePrior:
  """A zero-mean Gaussian prior on each camera's correction (rotation in radians, move in scene
  units): directions the images barely constrain stay near the given poses instead of drifting
  with the field's noise. `weight` times the mean over cameras of |ξ|² (params['poses'] float32
  [N, 6]). No stats."""
  name: ClassVar[str] = "pose_prior"
  weight: float

  def __call__(self, inputs):
    return self.weight * jnp.mean(jnp.sum(inputs.params["poses"] ** 2, axis=-1)), {}


def build(settings, context):
  """The term; None without pose refinement or at weight 0."""
  if not context.pose_refinement or settings.weight <= 0:
    return None
  return PosePrior(settings.weight)


LOSS = losses.Loss(PosePrior.name, Settings, build)
