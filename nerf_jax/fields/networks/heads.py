"""The layers the built-in networks share (Flax): Dense layers at the network's precision, the
per-image appearance codes and the colour branch. Each reads its sizes and numerics from the
network's settings (protocol.NetworkSettings); protocol.py: the calling convention every network
follows.
"""

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.backend import precision


def appearance_codes(module, shared, image, shape):
  """Per-training-image appearance codes (GLO, as NeRF-W and nerfacto): `module`'s parameter
  'appearance', a table float32 [shared.appearance_images, shared.appearance_dims] (zeros at the
  start). Returns codes [*shape[:-1], dims] for images int32 [...] whose axes lead `shape`'s
  (rays' images [R] for features [R, S, F]: each ray's code goes to all its samples; samples'
  own images [P] for features [P, F]), or the mean code for image None.
  A code conditions colour only, never density."""
  table = module.param("appearance", nn.initializers.zeros,
                       (shared.appearance_images, shared.appearance_dims))
  code = jnp.mean(table, axis=0) if image is None else table[image]
  spread = (1,) * (len(shape) - code.ndim)  # the axes the code is shared along
  code = code.reshape(code.shape[:-1] + spread + code.shape[-1:])
  return jnp.broadcast_to(code, (*shape[:-1], shared.appearance_dims))


def colour(module, shared, h, dir_features, image):
  """rgb float32 [..., 3] in (0, 1) from the hidden features h [..., C] of `module` (inside its
  compact call): the encoded direction (shared.view_dependent) and the appearance code
  (shared.appearance_dims; `appearance_codes`) joined, the colour layers, then 'rgb'."""
  extra = [dir_features] if shared.view_dependent else []
  if shared.appearance_dims:  # colour only: the code joins h after density is taken from it
    extra.append(appearance_codes(module, shared, image, h.shape))
  if extra:
    h = jnp.concatenate([h, *(e.astype(h.dtype) for e in extra)], axis=-1)
  if shared.view_dependent:
    h = colour_layers(shared, h)
  return nn.sigmoid(dense(shared, 3, "rgb")(h).astype(jnp.float32))


def colour_layers(shared, h):
  """The colour branch after the direction (and appearance code) joined h float [..., C]:
  `shared.view_depth` ReLU layers of `shared.view_width`, named 'view', 'view_1', ... (the
  first keeps the name single-layer checkpoints have always used), on the calling module."""
  if shared.view_depth < 1:
    raise ValueError(f"config.model.view_depth must be >= 1, got {shared.view_depth}")
  for i in range(shared.view_depth):
    h = nn.relu(dense(shared, shared.view_width, f"view_{i}" if i else "view")(h))
  return h


def dense(numerics, features, name):
  """A Dense layer of the calling module (inside its compact call): float32 parameters, the
  matmul dtype and float32 matmul precision of `numerics`, anything with `dtype` and
  `matmul_precision` (protocol.NetworkSettings; the transient head)."""
  return nn.Dense(features, dtype=jnp.dtype(numerics.dtype), param_dtype=jnp.float32, name=name,
                  precision=precision.network_precision(numerics.matmul_precision))
