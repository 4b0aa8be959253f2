"""Positional (Fourier-feature) encoding.

x: float32 [..., d] coordinates of order 1 (the scene fits in a few units around the origin).
The encoding is [x, sin(2^0 x), cos(2^0 x), ..., sin(2^(L-1) x), cos(2^(L-1) x)], channels last,
so `d + 2·d·L` features.

Accuracy: 2^k·x is exact in binary floating point (a power-of-two scale changes only the
exponent), so the only error is that of sin/cos of a float32 argument: the rounding of x itself
(relative 2^-24) is amplified by 2^k, i.e. an absolute error of about |x|·2^(k-24). For |x| <= 1 and
16 bands (k <= 15) that is <= 2^-9 ≈ 2e-3; at |x| = 1e3 the top bands are pure aliasing noise
(error of order 1), which is why scenes are scaled to coordinates of order 1.
sin and cos are both computed directly: cos(y) as sin(y + π/2) would round y + π/2 and lose up
to |y|·2^-24 more.
"""

import jax.numpy as jnp
import numpy as np


def positional_encoding(x, num_freqs):
  """Identity plus sin and cos of 2^k·x for k < num_freqs.

  x: float32 [..., d]. num_freqs: int >= 0. Returns float32 [..., d + 2·d·num_freqs].
  """
  if num_freqs == 0:
    return x
  # Built in numpy: exact powers of two (an XLA pow need not be exact).
  scales = jnp.asarray(2.0 ** np.arange(num_freqs), x.dtype)
  scaled = x[..., None, :] * scales[:, None]  # [..., L, d]
  features = jnp.concatenate([jnp.sin(scaled), jnp.cos(scaled)], axis=-1)  # [..., L, 2d]
  features = features.reshape(*x.shape[:-1], 2 * x.shape[-1] * num_freqs)
  return jnp.concatenate([x, features], axis=-1)


def encoded_width(dim, num_freqs):
  """Width of `positional_encoding` output for `dim` input channels."""
  return dim * (1 + 2 * num_freqs)
