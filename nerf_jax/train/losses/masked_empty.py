"""No opacity on the rays of masked pixels, where the masks keep the subject alone (a photo
collection's: config.loss.masked_empty).

Where each photo's mask keeps the subject's pixels alone and each ray is sampled within the
subject's depths (data.photo_bounds), a masked pixel sees past the subject: nothing on its ray
holds density. The colour loss never says so (a masked pixel has weight 0), so the space around
the subject that the visual hull keeps is free to hold a halo that some views explain. This term
adds the mean opacity of the batch's masked rays (those a patch batch draws beside its kept
pixels; a batch of kept pixels alone has none). A passer-by's masked pixel does see the subject
behind it: other photos outvote it, as they do in the visual hull (L1 on the opacity, a constant
pull that the colour of the photos that see the subject outweighs).
"""

import dataclasses
from typing import ClassVar

import jax.numpy as jnp

from nerf_jax.render import renderer
from nerf_jax.train import losses


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.loss.masked_empty."""
  weight: float = 0.0  # weight of the masked rays' mean opacity (0 = off)

  def __post_init__(self):
    losses.check_weight(self.weight, "masked_empty", "0.01")


@dataclasses.dataclass(frozen=True)
class MaskedEmpty:
  """weight x the mean opacity (acc) of the final pass over the batch's masked rays (0 where the
  batch has none). Stats: 'opacity' (that mean) and 'share' (the batch's masked share)."""
  name: ClassVar[str] = "masked_empty"
  weight: float

  def __call__(self, inputs):
    if inputs.mask is None:
      return jnp.zeros((), jnp.float32), {}
    masked = 1.0 - inputs.mask
    acc = renderer.final(inputs.outputs)["acc"]
    # At least one ray counted: a batch of kept pixels alone gives 0, not 0 / 0.
    opacity = jnp.sum(masked * acc) / jnp.maximum(jnp.sum(masked), 1.0)
    return self.weight * opacity, {"opacity": opacity, "share": jnp.mean(masked)}


def build(settings, context):
  """The term; None at weight 0."""
  del context
  return MaskedEmpty(settings.weight) if settings.weight > 0 else None


LOSS = losses.Loss(MaskedEmpty.name, Settings, build)
