"""The frequency bands (NeRF's positional encoding, config name 'posenc'; 'frequency' for
directions): the encoding's math, and its records (registry.Encoding).

x: float32 [..., d] coordinates of order 1 (the scene fits in a few units around the origin).
The encoding is [x, sin(2^0 x), cos(2^0 x), ..., sin(2^(L-1) x), cos(2^(L-1) x)], channels last,
so `d + 2·d·L` features.

Accuracy (tests/topics/test_numerics.py, case 10): 2^k·x is exact in binary floating point (a power
of two changes only the exponent), so against float64 sin/cos of the same float32 input every band
is within 2.5e-7 (measured 3.3e-8 on XLA:CPU, for |x| <= 1 and at |x| = 1e3 alike). Against the
real-valued coordinate before its rounding to float32 (relative 2^-24), band k also carries that
rounding amplified by 2^k: up to |x|·2^(k-24), i.e. 2^-9 ≈ 2e-3 for |x| <= 1 and k = 15. At |x| =
1e3 the bands k >= 11 may be off by more than 0.1 and the top ones by order 1: aliasing noise, which
is why scenes are scaled to coordinates of order 1. Pass float32 x: in bfloat16 the rounding is 2^-8
and band 15 of |x| = 1 is off by order 1 as well. sin and cos are both computed directly: cos(y) as
sin(y + π/2) would round y + π/2 and lose up to ulp(y)/2 more (2e-3 at |y| = 2^15). """

import dataclasses

import jax.numpy as jnp
import numpy as np

from nerf_jax.fields import registry


def positional_encoding(x, num_freqs, band_weights=None):
  """Identity plus sin and cos of 2^k·x for k < num_freqs.

  x: float32 [..., d]. num_freqs: int >= 0. band_weights: None, or float32 [num_freqs] factors
  of each band's sin and cos (`coarse_to_fine_weights`). Returns float32
  [..., d + 2·d·num_freqs].
  """
  if num_freqs == 0:
    return x
  # Built in numpy: exact powers of two (an XLA pow need not be exact).
  scales = jnp.asarray(2.0 ** np.arange(num_freqs), x.dtype)
  scaled = x[..., None, :] * scales[:, None]  # [..., L, d]
  features = jnp.concatenate([jnp.sin(scaled), jnp.cos(scaled)], axis=-1)  # [..., L, 2d]
  if band_weights is not None:
    features = features * jnp.asarray(band_weights, x.dtype)[:, None]
  features = features.reshape(*x.shape[:-1], 2 * x.shape[-1] * num_freqs)
  return jnp.concatenate([x, features], axis=-1)


def encoded_width(dim, num_freqs):
  """Width of `positional_encoding` output for `dim` input channels."""
  return dim * (1 + 2 * num_freqs)


def coarse_to_fine_weights(alpha, num_freqs):
  """BARF's window over the bands (Lin et al. 2021, eq. 14): band k has weight
  (1 - cos(π·clip(alpha - k, 0, 1))) / 2, so bands open one after another as alpha goes from 0
  to num_freqs; every weight is exactly 1 once alpha >= num_freqs (cos(π) = -1).

  alpha: float32 [] (possibly traced). Returns float32 [num_freqs].
  """
  k = jnp.arange(num_freqs, dtype=jnp.float32)
  return 0.5 * (1.0 - jnp.cos(jnp.pi * jnp.clip(alpha - k, 0.0, 1.0)))


@dataclasses.dataclass(frozen=True)
class Frequency:
  """The encoding of coordinates by `num_freqs` bands (protocol.Encoding): no parameters; the
  bands open one after another while poses are refined."""
  num_freqs: int

  @property
  def coarse_to_fine_stages(self):
    return self.num_freqs

  def band_weights(self, bands):
    """float32 [num_freqs]: `coarse_to_fine_weights` of alpha = bands."""
    return coarse_to_fine_weights(bands, self.num_freqs)

  def features(self, module, x, weights=None):
    """`positional_encoding` of x float32 [..., d] (module: unused, no parameters)."""
    del module
    if weights is None:
      return positional_encoding(x, self.num_freqs)
    return positional_encoding(x, self.num_freqs, weights)

  def inside(self, points):
    del points
    return None  # all of space

  def width(self, dim):
    return encoded_width(dim, self.num_freqs)


@dataclasses.dataclass(frozen=True)
class Settings:
  """config's top-level field of the positions' bands (model.encoding 'posenc')."""
  pos_encode_dims: int = 10  # POS_ENCODE_DIMS: frequency bands for positions

  def __post_init__(self):
    if self.pos_encode_dims < 0:
      raise ValueError(f"config.pos_encode_dims={self.pos_encode_dims}: use 0 (the positions "
                       "alone) or more bands")


def build(settings, shared):
  """The Frequency encoding of the positions (shared: unused)."""
  del shared
  return Frequency(settings.pos_encode_dims)


# Its bands are a top-level field (config.pos_encode_dims), recorded among the signature's
# shared fields by run/signature.model_signature, as they always were: nothing of its own here.
ENCODING = registry.Encoding("posenc", Settings, build, lambda settings: {}, section="",
                             network="mlp")
