"""The radiance-field MLP (the only module that imports flax.linen).

Inputs are already encoded (see encoding.py):
  pos_features: float32 [..., Dp]  encoded sample positions
  dir_features: float32 [..., Dd]  encoded unit viewing directions (only if view_dependent)
Outputs:
  rgb:       float32 [..., 3]  colour in (0, 1) (sigmoid)
  raw_sigma: float32 [...]     density before its activation (renderer.py adds noise, activates)
"""

from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp


class NerfMLP(nn.Module):
  """NeRF's MLP: `depth` ReLU layers of `width` with the input re-injected after `skip_layers`.

  view_dependent=False is the reference's position-only model (one linear head of 4 outputs).
  view_dependent=True is the paper's 5D model: density from position only; colour from a `width`
  feature plus the encoded direction through one ReLU layer of `view_width`.
  dtype is the matmul dtype (float32, bfloat16 or float16); parameters stay float32 and the
  outputs are cast back to float32 so compositing is always done in float32.
  """
  depth: int = 8
  width: int = 256
  skip_layers: Sequence[int] = (4,)
  view_dependent: bool = False
  view_width: int = 128
  dtype: str = "float32"

  def _dense(self, features, name):
    return nn.Dense(features, dtype=jnp.dtype(self.dtype), param_dtype=jnp.float32, name=name)

  @nn.compact
  def __call__(self, pos_features, dir_features=None):
    x = pos_features.astype(jnp.dtype(self.dtype))
    inputs = x
    for i in range(self.depth):
      x = nn.relu(self._dense(self.width, f"layer_{i}")(x))
      if i in self.skip_layers:
        x = jnp.concatenate([x, inputs], axis=-1)
    if not self.view_dependent:
      out = self._dense(4, "output")(x).astype(jnp.float32)
      return nn.sigmoid(out[..., :3]), out[..., 3]
    raw_sigma = self._dense(1, "sigma")(x)[..., 0].astype(jnp.float32)
    feature = self._dense(self.width, "feature")(x)
    h = jnp.concatenate([feature, dir_features.astype(feature.dtype)], axis=-1)
    h = nn.relu(self._dense(self.view_width, "view")(h))
    rgb = self._dense(3, "rgb")(h).astype(jnp.float32)
    return nn.sigmoid(rgb), raw_sigma


def make_model(model_config):
  """The NerfMLP described by `config.model` (a ConfigDict)."""
  return NerfMLP(depth=model_config.depth, width=model_config.width,
                 skip_layers=tuple(model_config.skip_layers),
                 view_dependent=model_config.view_dependent,
                 view_width=model_config.view_width, dtype=model_config.dtype)
