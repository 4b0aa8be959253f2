"""The layers the built-in networks share (Flax): Dense layers at the network's precision, the
per-image appearance codes and the colour branch. protocol.py: the calling convention every
network follows.
"""

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.backend import precision


def appearance_codes(module, image, shape):
  """Per-training-image appearance codes (GLO, as NeRF-W and nerfacto): `module`'s parameter
  'appearance', a table float32 [appearance_images, appearance_dims] (zeros at the start).
  Returns codes [*shape[:-1], dims] for rays' images int32 [...] (shape = the features'
  [..., S, F]: each ray's code goes to all its samples), or the mean code for image None.
  A code conditions colour only, never density."""
  table = module.param("appearance", nn.initializers.zeros,
                       (module.appearance_images, module.appearance_dims))
  code = jnp.mean(table, axis=0) if image is None else table[image][..., None, :]
  return jnp.broadcast_to(code, (*shape[:-1], module.appearance_dims))


def colour_layers(network, h):
  """The colour branch after the direction (and appearance code) joined h float [..., C]:
  `network.view_depth` ReLU layers of `view_width`, named 'view', 'view_1', ... (the first
  keeps the name single-layer checkpoints have always used)."""
  if network.view_depth < 1:
    raise ValueError(f"config.model.view_depth must be >= 1, got {network.view_depth}")
  for i in range(network.view_depth):
    h = nn.relu(dense(network, network.view_width, f"view_{i}" if i else "view")(h))
  return h


def dense(network, features, name):
  """A Dense layer of `network` (inside its compact call): float32 parameters, the network's
  matmul dtype and float32 matmul precision (its `dtype` and `matmul_precision` fields)."""
  return nn.Dense(features, dtype=jnp.dtype(network.dtype), param_dtype=jnp.float32, name=name,
                  precision=precision.network_precision(network.matmul_precision))


