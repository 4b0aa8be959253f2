"""The transient field of NeRF-W (section 4.2): what stands in one training photo and not in
the others (people, boats, cars), with a per-sample uncertainty. It wraps the Flax head of
networks/transient_head.py and activates its outputs; render/renderer.py queries it on the final pass
of training rays (which carry their image) and composites it with the static field
(render/compositing.composite_with_transient). Held-out views and renders (rays without an
image) see the static field alone.

Names and axes:
  points: float32 [..., S, 3]  the static network's points (Field.network_points)
  image:  int32 [...]          each ray's training image
  rgb:    float32 [..., S, 3]  transient colour c_tau in (0, 1)
  sigma:  float32 [..., S]     transient density sigma_tau >= 0, per unit of world length
  beta:   float32 [..., S]     per-sample uncertainty >= 0 (beta_min is added once rendered)
"""

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from nerf_jax.fields import activations
from nerf_jax.fields.networks import transient_head


@dataclasses.dataclass(frozen=True)
class TransientField:
  """network: the TransientHead (networks/transient_head.py). beta_min: the floor added to the
  rendered uncertainty. density_shift: added to the raw density before the softplus."""
  network: Any
  beta_min: float = transient_head.Settings.beta_min  # defaults: the settings' (declared once)
  density_shift: float = transient_head.Settings.density_shift

  def init(self, key):
    """The head's parameters (its embedding table and MLP), from PRNG key `key`."""
    points = jnp.zeros((1, 1, 3), jnp.float32)
    return jax.jit(self.network.init)(key, points, jnp.zeros((1,), jnp.int32))["params"]

  def query(self, params, points, image):
    """(rgb float32 [..., S, 3], sigma float32 [..., S], beta float32 [..., S]) at points
    float32 [..., S, 3] of rays whose training images are image int32 [...].

    Density and uncertainty are softplus'd (NeRF-W's activations; softplus is finite with a
    finite gradient for any finite raw value, activations.shifted_softplus)."""
    rgb, raw_sigma, raw_beta = self.network.apply({"params": params}, points, image)
    sigma = activations.shifted_softplus(raw_sigma, self.density_shift)
    beta = activations.shifted_softplus(raw_beta, 0.0)
    return rgb, sigma, beta
