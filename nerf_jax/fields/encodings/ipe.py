"""Integrated positional encoding (mip-NeRF, Barron et al. 2021): a Gaussian's expected features.

For x ~ N(mean, diag(var)), E[sin(w x)] = sin(w·mean)·exp(-w^2 var / 2), and the same for cos:
each band 2^k of the positional encoding is damped by exp(-4^k var / 2), so frequencies finer
than the Gaussian's spread fade away instead of aliasing.

Layout: the same as encoding.positional_encoding, feature for feature,
  [mean, sin(2^k mean)·a_k, cos(2^k mean)·a_k for k < L],  a_k = exp(-4^k var / 2),
width d + 2·d·L. The identity part is the mean: it is E[x], the Gaussian's expected identity
feature (undamped: x is linear). It is computed as positional_encoding(mean) times the damping,
so for var = 0 (a_k = exp(-0) = 1 exactly) the output is positional_encoding's bit for bit:
a zero radius gives exactly the point encoding.

Names and axes:
  mean: float32 [..., d]  the Gaussian's mean (d = 3 for positions)
  var:  float32 [..., d]  its covariance's diagonal, >= 0 (the encoding needs nothing else: each
                          feature depends on one coordinate)

Numerics (float32): 4^k·var overflows to inf for huge var (far samples, contracted space; 4^15
~ 1.1e9), and exp(-inf) = 0 exactly, so those features are 0; the gradient w.r.t. var is then
-4^k/2·0 = 0 and w.r.t. mean cos(...)·2^k·0 = 0: no inf·0 appears, since the only infinite
value (the exponent) meets the derivative of exp, which is exp itself. Bands up to L = 16 are
finite (2^15·mean is exact: a power of two; see encoding.py for their accuracy).
"""

import dataclasses

import jax.numpy as jnp
import numpy as np

from nerf_jax.fields import registry
from nerf_jax.fields.encodings import posenc
from nerf_jax.fields.encodings.posenc import positional_encoding


def band_damping(var, num_freqs):
  """exp(-4^k var / 2) for k < num_freqs: how much band k survives the Gaussian's spread.

  var: float32 [..., d], >= 0. Returns float32 [..., num_freqs, d], in [0, 1]; exactly 1 where
  var = 0.
  """
  # Built in numpy: exact powers of four (an XLA pow need not be exact).
  half_squares = jnp.asarray(0.5 * 4.0 ** np.arange(num_freqs), var.dtype)
  return jnp.exp(-half_squares[:, None] * var[..., None, :])


def integrated_positional_encoding(mean, var, num_freqs, band_weights=None):
  """The mean, and the damped sin and cos of 2^k·mean for k < num_freqs.

  mean: float32 [..., d]. var: float32 [..., d], >= 0, the covariance's diagonal. num_freqs:
  int >= 0. band_weights: None, or float32 [num_freqs], coarse-to-fine factors of each band
  (encoding.coarse_to_fine_weights), applied as positional_encoding applies them.
  Returns float32 [..., d + 2·d·num_freqs], in positional_encoding's order; equal to
  positional_encoding(mean, num_freqs, band_weights) bit for bit where var = 0.
  """
  features = positional_encoding(mean, num_freqs, band_weights)
  if num_freqs == 0:
    return features
  damping = band_damping(var, num_freqs)  # [..., L, d]
  # Each band's sin block and cos block share its damping: [..., L, 2d], as the features.
  damping = jnp.concatenate([damping, damping], axis=-1)
  damping = damping.reshape(*damping.shape[:-2], -1)
  identity = jnp.ones_like(mean)  # the mean is E[x]: not damped
  return features * jnp.concatenate([identity, damping], axis=-1)


@dataclasses.dataclass(frozen=True)
class Integrated(posenc.Frequency):
  """The integrated encoding of Gaussians by `num_freqs` bands (protocol.Encoding, config name
  'ipe'): NeRF's MLP reads it as it reads the bands; no parameters."""

  def features(self, module, x, weights=None, var=None):
    """`integrated_positional_encoding` of means x float32 [..., d] with diagonal variances var
    float32 [..., d] (None or 0: points, positional_encoding exactly). module: unused."""
    if var is None:
      return super().features(module, x, weights)
    return integrated_positional_encoding(x, var, self.num_freqs, weights)


def build(settings, shared):
  """The Integrated encoding of the positions: posenc's settings (config.pos_encode_dims bands;
  shared: unused)."""
  del shared
  return Integrated(settings.pos_encode_dims)


# The bands' setting is posenc's (config.pos_encode_dims, recorded with the shared fields by
# run/signature.py): its checkpoints record only that they are ipe's (posenc's have the same
# shapes).
ENCODING = registry.Encoding("ipe", posenc.Settings, build, network="mlp", section="",
                             signature=lambda settings: {"encoding": "ipe"}, cones="gaussians")
