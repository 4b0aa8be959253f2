"""NeRF-W's transient head (Flax; Martin-Brualla et al. 2021, section 4.2): per-training-image
transient embeddings and a small MLP that gives each sample a transient density, a transient
colour and an uncertainty. Its settings are config.model.transient (`Settings`); the field's
side (fields/transient_field.py) queries it, render/compositing.composite_with_transient composites
it with the static field.

Unlike NeRF-W, whose transient branch reads the static MLP's trunk, the head reads the points'
own frequency bands: it sits beside any network (mlp, lattice, grid) without changing it, and
the static field's parameters stay exactly as they were.

  head.apply({'params': p}, points, image) -> (rgb float32 [..., S, 3] in (0, 1),
      raw_sigma float32 [..., S], raw_beta float32 [..., S])

  points: float32 [..., S, 3], the static network's points (contracted in an unbounded scene).
  image:  int32 [...], each ray's training image (its transient embedding).
"""

import dataclasses

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.backend import draws
from nerf_jax.fields.encodings import posenc
from nerf_jax.fields.networks import heads


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model.transient: NeRF-W's transient head (dims 0 = off)."""
  dims: int = 0  # length of each training image's transient embedding (NeRF-W: 16; 0 = off)
  width: int = 64  # units per hidden layer of the transient MLP (NeRF-W: 128)
  depth: int = 3  # hidden ReLU layers of the transient MLP (NeRF-W: 4)
  pos_bands: int = 6  # frequency bands of the positions the transient MLP reads
  beta_min: float = 0.03  # floor of the rendered uncertainty beta (NeRF-W's beta_min)
  density_shift: float = -4.0  # added to the raw transient density: softplus(-4) = 0.018, so
  # the head starts nearly transparent and the static field learns first

  def __post_init__(self):
    for name in ("dims", "width", "depth", "pos_bands"):
      if getattr(self, name) < 0:
        raise ValueError(f"config.model.transient.{name}={getattr(self, name)}: use a value "
                         ">= 0 (dims 0 = off; NeRF-W: dims 16)")
    if self.dims and self.beta_min <= 0:
      raise ValueError(f"config.model.transient.beta_min={self.beta_min}: use a floor > 0 "
                       "(NeRF-W: 0.03); the loss divides by beta squared")


class TransientHead(nn.Module):
  """The transient MLP of `settings` (`Settings`): the points' pos_bands frequency bands and the
  ray's image embedding through `depth` ReLU layers of `width`, then a linear output of raw
  density, colour and raw uncertainty. The embedding table 'embedding' float32 [images, dims]
  starts at N(0, 1) draws (as torch's Embedding of NeRF-W's code), so the images' heads differ
  from the first step. images: the training images (from the data). dtype, matmul_precision:
  the matmul dtype and float32 precision (config.model's, as the static network's)."""
  settings: Settings
  images: int
  dtype: str
  matmul_precision: str  # precision.NETWORK_PRECISIONS: 'default', 'high', 'highest'

  @nn.compact
  def __call__(self, points, image):
    s = self.settings
    table = self.param("embedding", draws.normal_init(1.0), (self.images, s.dims))
    code = jnp.broadcast_to(table[image][..., None, :], (*points.shape[:-1], s.dims))
    x = jnp.concatenate([posenc.positional_encoding(points, s.pos_bands), code], axis=-1)
    x = x.astype(jnp.dtype(self.dtype))
    for i in range(s.depth):
      x = nn.relu(heads.dense(self, s.width, f"layer_{i}")(x))
    out = heads.dense(self, 5, "output")(x).astype(jnp.float32)
    return nn.sigmoid(out[..., :3]), out[..., 3], out[..., 4]


def build(settings, images, dtype, matmul_precision):
  """The TransientHead of `settings` for `images` training images, matmuls in `dtype` at
  `matmul_precision` (None when settings.dims is 0)."""
  if not settings.dims:
    return None
  return TransientHead(settings, max(int(images), 1), dtype, matmul_precision)
