"""The lattice head (network 'lattice'): the grids' tiny MLP (instant-ngp's, DVGO's), the
network that reads a lattice encoding ('grid', 'hash', 'tensorf') unless config.model.network
names another; it reads any encoding's features. Its hidden width is config.model.width.

Density and a feature come from one hidden layer over the encoding's features; colour from the
feature (and the encoded direction, and the appearance code). Positions outside what the
encoding covers (a lattice's box) get raw density -1e5, which every density activation maps to
0 with a zero gradient (relu, softplus and exp all underflow to exactly 0 there). See
protocol.py for its call.
"""

from typing import Any

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.fields import protocol, registry
from nerf_jax.fields.networks import heads


def head(network, h, inside, dir_features, image=None):
  """(rgb float32 [..., 3] in (0, 1), raw_sigma float32 [...]) of features h [..., F] in the
  dtype of `network` (a module with `shared`, protocol.NetworkSettings): density and a feature
  from one hidden layer of shared.width, colour from the feature (and direction, and appearance
  code). inside: bool [...] or None, where density may be non-zero."""
  s = network.shared
  h = nn.relu(heads.dense(s, s.width, "hidden")(h))
  raw_sigma = heads.dense(s, 1, "sigma")(h)[..., 0].astype(jnp.float32)
  if inside is not None:
    raw_sigma = jnp.where(inside, raw_sigma, -1e5)
  return heads.colour(network, s, h, dir_features, image), raw_sigma


class LatticeHead(nn.Module):
  """An encoding's features (protocol.Encoding, applied to the points) + the tiny head.
  shared: the settings every network shares (protocol.NetworkSettings: its hidden width is
  shared.width). level_weights: float32 or None, the encoding's coarse-to-fine window (pose
  refinement)."""
  encoding: Any
  shared: protocol.NetworkSettings

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None, **per_sample):
    h = self.encoding.features(self, points, level_weights, **per_sample)
    return head(self, h.astype(jnp.dtype(self.shared.dtype)), self.encoding.inside(points),
                dir_features, image)

  @property
  def coarse_to_fine_stages(self):
    return self.encoding.coarse_to_fine_stages

  def band_weights(self, bands):
    return self.encoding.band_weights(bands)

  @property
  def splits_density(self):
    """Density and colour come from one head (protocol.Network)."""
    return False


def build(encoding, settings, shared):
  """The LatticeHead over `encoding`, config.model.width wide (protocol.NetworkSettings)."""
  del settings  # none of its own
  return LatticeHead(encoding, shared)


NETWORK = registry.Network("lattice", None, build)
