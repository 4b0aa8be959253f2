"""The 'posenc' family: NeRF's MLP on positionally encoded positions (encodings/encoding.py).

Inputs are already encoded: pos_features float32 [..., Dp], dir_features float32 [..., Dd] (only
if view_dependent), image int32 [...] or None (appearance_dims > 0); see network.py. Its settings
are config.model's depth, width and skip_layers; the bands are config.pos_encode_dims.
"""

import dataclasses
from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.fields import registry
from nerf_jax.fields.networks import heads


class NerfMLP(nn.Module):
  """NeRF's MLP: `depth` ReLU layers of `width` with the input re-injected after `skip_layers`.

  view_dependent=False is the reference's position-only model (one linear head of 4 outputs).
  view_dependent=True is the paper's 5D model: density from position only; colour from a `width`
  feature plus the encoded direction through `view_depth` ReLU layers of `view_width`.
  dtype is the matmul dtype (float32, bfloat16 or float16); parameters stay float32 and the
  outputs are cast back to float32 so compositing is always done in float32. matmul_precision
  is the float32 matmuls' precision (nerf_jax.backend.precision: 'default' is TF32 on recent GPUs).
  """
  depth: int = 8
  width: int = 256
  skip_layers: Sequence[int] = (4,)
  view_dependent: bool = False
  view_width: int = 128
  view_depth: int = 1
  dtype: str = "float32"
  matmul_precision: str = "default"  # precision.NETWORK_PRECISIONS: 'default', 'high', 'highest'
  appearance_images: int = 1
  appearance_dims: int = 0

  @nn.compact
  def __call__(self, pos_features, dir_features=None, image=None):
    x = pos_features.astype(jnp.dtype(self.dtype))
    inputs = x
    for i in range(self.depth):
      x = nn.relu(heads.dense(self, self.width, f"layer_{i}")(x))
      if i in self.skip_layers:
        x = jnp.concatenate([x, inputs], axis=-1)
    if not self.view_dependent:
      if not self.appearance_dims:
        out = heads.dense(self, 4, "output")(x).astype(jnp.float32)
        return nn.sigmoid(out[..., :3]), out[..., 3]
      # The reference's head split in two: density from x alone, colour from x and the code.
      raw_sigma = heads.dense(self, 1, "sigma")(x)[..., 0].astype(jnp.float32)
      code = heads.appearance_codes(self, image, x.shape).astype(x.dtype)
      rgb = heads.dense(self, 3, "rgb")(jnp.concatenate([x, code], axis=-1)).astype(jnp.float32)
      return nn.sigmoid(rgb), raw_sigma
    raw_sigma = heads.dense(self, 1, "sigma")(x)[..., 0].astype(jnp.float32)
    feature = heads.dense(self, self.width, "feature")(x)
    extra = [dir_features]
    if self.appearance_dims:  # the code joins the direction in the colour branch
      extra.append(heads.appearance_codes(self, image, feature.shape))
    h = jnp.concatenate([feature, *(e.astype(feature.dtype) for e in extra)], axis=-1)
    h = heads.colour_layers(self, h)
    rgb = heads.dense(self, 3, "rgb")(h).astype(jnp.float32)
    return nn.sigmoid(rgb), raw_sigma


  @property
  def num_levels(self):
    """0: the Field opens the positional encoding's bands coarse to fine instead."""
    return 0

  @property
  def splits_density(self):
    return False


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model's fields of the MLP."""
  depth: int = 8  # ReLU layers
  width: int = 256  # units per layer
  skip_layers: Sequence[int] = (4,)  # layers after which the input is concatenated again


def build(settings, shared):
  """The NerfMLP of `settings` and the shared network settings (network.NetworkSettings)."""
  return NerfMLP(depth=settings.depth, width=settings.width,
                 skip_layers=tuple(settings.skip_layers), **shared.head)


# The MLP's checkpoints record depth, width and skip_layers with the model's shared fields
# (run/experiment.model_signature), as they always have: nothing of its own here.
ENCODING = registry.Encoding("posenc", Settings, build, raw_positions=False, section="model")
