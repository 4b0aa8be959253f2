"""NeRF's MLP (network 'mlp'): the network that reads the frequency bands ('posenc') unless
config.model.network names another; it reads any encoding's features. Its settings are
config.model's depth and skip_layers (`Settings`) and the shared ones (width, view_width...:
protocol.NetworkSettings). See protocol.py for its call.
"""

import dataclasses
from typing import Any, Sequence

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.fields import protocol, registry
from nerf_jax.fields.networks import heads


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model's fields of the MLP (its width is the shared model.width,
  protocol.NetworkSettings)."""
  depth: int = 8  # hidden layers
  skip_layers: Sequence[int] = (4,)  # re-inject the input after these layers (0-based)


class NerfMLP(nn.Module):
  """NeRF's MLP: settings.depth ReLU layers of shared.width with the input re-injected after
  settings.skip_layers.

  settings: its own (`Settings`). shared: the settings every network shares
  (protocol.NetworkSettings). encoding: the position encoding it applies to its input points
  (protocol.Encoding); None: the input is already features float32 [..., D] (encoded by the
  caller).
  shared.view_dependent False is the reference's position-only model (one linear head of 4
  outputs); True is the paper's 5D model: density from position only; colour from a `width`
  feature plus the encoded direction through `view_depth` ReLU layers of `view_width`.
  shared.dtype is the matmul dtype (float32, bfloat16 or float16); parameters stay float32 and
  the outputs are cast back to float32 so compositing is always done in float32;
  shared.matmul_precision is the float32 matmuls' precision (nerf_jax.backend.precision:
  'default' is TF32 on recent GPUs). With shared.appearance_dims > 0 a per-image code joins the
  colour. Where the encoding covers only a box (a lattice's), density outside it is raw -1e5.
  """
  settings: Settings
  shared: protocol.NetworkSettings
  encoding: Any = None  # None: no encoding (the caller's features)

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
    s = self.shared
    x = pos_features.astype(jnp.dtype(s.dtype))
    inputs = x
    for i in range(self.settings.depth):
      x = nn.relu(heads.dense(s, s.width, f"layer_{i}")(x))
      if i in self.settings.skip_layers:
        x = jnp.concatenate([x, inputs], axis=-1)
    if not s.view_dependent:
      if not s.appearance_dims:
        out = heads.dense(s, 4, "output")(x).astype(jnp.float32)
        return nn.sigmoid(out[..., :3]), out[..., 3]
      # The reference's head split in two: density from x alone, colour from x and the code.
      raw_sigma = heads.dense(s, 1, "sigma")(x)[..., 0].astype(jnp.float32)
      code = heads.appearance_codes(self, s, image, x.shape).astype(x.dtype)
      rgb = heads.dense(s, 3, "rgb")(jnp.concatenate([x, code], axis=-1)).astype(jnp.float32)
      return nn.sigmoid(rgb), raw_sigma
    raw_sigma = heads.dense(s, 1, "sigma")(x)[..., 0].astype(jnp.float32)
    feature = heads.dense(s, s.width, "feature")(x)
    extra = [dir_features]
    if s.appearance_dims:  # the code joins the direction in the colour branch
      extra.append(heads.appearance_codes(self, s, image, feature.shape))
    h = jnp.concatenate([feature, *(e.astype(feature.dtype) for e in extra)], axis=-1)
    h = heads.colour_layers(s, h)
    rgb = heads.dense(s, 3, "rgb")(h).astype(jnp.float32)
    return nn.sigmoid(rgb), raw_sigma

  @property
  def coarse_to_fine_stages(self):
    return 0 if self.encoding is None else self.encoding.coarse_to_fine_stages

  def band_weights(self, bands):
    return self.encoding.band_weights(bands)

  @property
  def splits_density(self):
    return False


def build(encoding, settings, shared):
  """The NerfMLP over `encoding` of `settings` and the shared settings
  (protocol.NetworkSettings)."""
  settings = dataclasses.replace(settings, skip_layers=tuple(settings.skip_layers))
  return NerfMLP(settings, shared, encoding)


# Its section is config.model, shared with the other networks' common settings (as it always
# was: model.depth, model.skip_layers).
NETWORK = registry.Network("mlp", Settings, build, section="model")
