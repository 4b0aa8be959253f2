"""NeRF's MLP (network 'mlp'): the network that reads the frequency bands ('posenc') unless
config.model.network names another; it reads any encoding's features. Its settings are
config.model's depth, width and skip_layers (`Settings`). See protocol.py for its call.
"""

import dataclasses
from typing import Any, Sequence

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.fields import registry
from nerf_jax.fields.networks import heads


class NerfMLP(nn.Module):
  """NeRF's MLP: `depth` ReLU layers of `width` with the input re-injected after `skip_layers`.

  encoding: the position encoding it applies to its input points (protocol.Encoding); None: the
  input is already features float32 [..., D] (encoded by the caller).
  view_dependent=False is the reference's position-only model (one linear head of 4 outputs).
  view_dependent=True is the paper's 5D model: density from position only; colour from a `width`
  feature plus the encoded direction through `view_depth` ReLU layers of `view_width`.
  dtype is the matmul dtype (float32, bfloat16 or float16); parameters stay float32 and the
  outputs are cast back to float32 so compositing is always done in float32. matmul_precision
  is the float32 matmuls' precision (nerf_jax.backend.precision: 'default' is TF32 on recent GPUs).
  Where the encoding covers only a box (a lattice's), density outside it is raw -1e5.
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
  encoding: Any = None

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None, **per_sample):
    rgb, raw_sigma = self._layers(self._encode(points, level_weights, per_sample), dir_features,
                                  image)
    inside = None if self.encoding is None else self.encoding.inside(points)
    if inside is not None:
      raw_sigma = jnp.where(inside, raw_sigma, -1e5)
    return rgb, raw_sigma

  def _encode(self, points, level_weights, per_sample):
    if self.encoding is None:
      return points
    # per_sample (a cone's: protocol.py) only when given, so encodings of points need not take it
    return self.encoding.features(self, points, level_weights, **per_sample)

  def _layers(self, pos_features, dir_features, image):
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
  def coarse_to_fine_stages(self):
    return 0 if self.encoding is None else self.encoding.coarse_to_fine_stages

  def band_weights(self, bands):
    return self.encoding.band_weights(bands)

  @property
  def splits_density(self):
    return False


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model's fields of the MLP (its width is the shared model.width,
  protocol.NetworkSettings)."""
  depth: int = 8  # hidden layers
  skip_layers: Sequence[int] = (4,)  # re-inject the input after these layers (0-based)


def build(encoding, settings, shared):
  """The NerfMLP over `encoding` of `settings` and the shared settings
  (protocol.NetworkSettings)."""
  return NerfMLP(depth=settings.depth, width=shared.width,
                 skip_layers=tuple(settings.skip_layers), encoding=encoding, **shared.head)


# Its section is config.model, shared with the other networks' common settings (as it always
# was: model.depth, model.skip_layers).
NETWORK = registry.Network("mlp", Settings, build, section="model")
