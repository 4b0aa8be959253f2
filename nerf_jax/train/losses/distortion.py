"""mip-NeRF 360's distortion loss as a term (config.loss.distortion; the per-ray loss is
train/regularizers.distortion)."""

import dataclasses
from typing import Callable, ClassVar

import jax
import jax.numpy as jnp

from nerf_jax.render import renderer
from nerf_jax.train import losses, regularizers


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.loss.distortion."""
  weight: float = 0.0  # weight of the distortion loss, ray distance in [0, 1] (0 = off)

  def __post_init__(self):
    losses.check_weight(self.weight, "distortion", "0.02")


@dataclasses.dataclass(frozen=True)
class Distortion:
  """mip-NeRF 360's distortion loss: each ray's weight kept in one place (no floaters).

  In normalised ray distance (mip-NeRF 360's s, `unit_distance(t, rays)`: the sampler's): the
  same weight at any scene scale, and finite for an unbounded scene's edges out to 1e10. It
  shapes the weights only: no gradient reaches the cameras (pose refinement) through the edges.
  No stats.
  """
  name: ClassVar[str] = "distortion"
  weight: float
  unit_distance: Callable

  def __call__(self, inputs):
    last = renderer.final(inputs.outputs)
    s = jax.lax.stop_gradient(self.unit_distance(last["t"], inputs.rays))
    return self.weight * jnp.mean(regularizers.distortion(s, last["weights"])), {}


def build(settings, context):
  """The term, on the training sampler's ray distance; None at weight 0."""
  if settings.weight <= 0:
    return None
  return Distortion(settings.weight, context.ray_renderer.sampler.unit_distance)


LOSS = losses.Loss(Distortion.name, Settings, build)
