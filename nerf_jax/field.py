"""The radiance field: the model's parameters and its queries at sample points.

A field maps points float32 [..., S, 3] and unit view directions float32 [..., 3] to colour
rgb float32 [..., S, 3] and density sigma float32 [..., S] (per unit of world length). It wraps
the Flax model (model.py) with the encoding of its inputs (encoding.py; the grid models take raw
positions, the grids are their encoding) and the density activation (activations.py).
"""

import jax
import jax.numpy as jnp

from nerf_jax import activations, encoding, occupancy


def network_names(config):
  """Parameter groups: a fine network exists only with hierarchical sampling and unshared nets."""
  if config.num_fine_samples > 0 and not config.model.shared_fine:
    return ("coarse", "fine")
  return ("coarse",)


def encodes_positions(config):
  """Whether positions go through positional encoding (the MLP) or raw into a grid model."""
  return config.model.encoding == "posenc"


def init_params(model, config, key):
  """Parameters {'coarse': ..., ['fine': ...], ['occupancy': float32 [R, R, R]]} for `model`.

  The occupancy grid starts at zeros, which counts as occupied everywhere (see occupancy.py).
  """
  occupancy.check_config(config)
  pos_width = encoding.encoded_width(3, config.pos_encode_dims) if encodes_positions(config) else 3
  pos = jnp.zeros((1, pos_width), jnp.float32)
  dirs = jnp.zeros((1, encoding.encoded_width(3, config.dir_encode_dims)), jnp.float32)
  keys = jax.random.split(key, 2)
  params = {name: model.init(k, pos, dirs)["params"]
            for name, k in zip(network_names(config), keys)}
  if occupancy.enabled(config):
    res = config.occupancy.resolution
    params["occupancy"] = jnp.zeros((res, res, res), jnp.float32)
  return params


def query(model, params, points, viewdirs, config, key=None):
  """Colour and density at sample points.

  params: one network's parameters. points: float32 [..., S, 3]. viewdirs: float32 [..., 3]
  unit directions. key: PRNG key for the density noise (None = no noise).
  Returns rgb float32 [..., S, 3], sigma float32 [..., S].
  """
  if encodes_positions(config):
    pos_features = encoding.positional_encoding(points, config.pos_encode_dims)
  else:
    pos_features = points  # the grids are the encoding
  dir_features = None
  if config.model.view_dependent:
    dirs = jnp.broadcast_to(viewdirs[..., None, :], points.shape)
    dir_features = encoding.positional_encoding(dirs, config.dir_encode_dims)
  rgb, raw_sigma = model.apply({"params": params}, pos_features, dir_features)
  if key is not None and config.model.density_noise > 0:
    # The paper's regulariser: noise on the raw output, before the activation keeps sigma >= 0.
    raw_sigma = raw_sigma + config.model.density_noise * jax.random.normal(key, raw_sigma.shape)
  sigma = activations.density_activation(config.model.density_activation)(raw_sigma)
  return rgb, sigma


def query_in_chunks(model, params, points, viewdirs, config, key=None, chunk=0):
  """`query` over chunks of `chunk` rays, each rematerialised in the backward pass.

  points: float32 [R, S, 3], viewdirs: float32 [R, 3]. chunk: rays per chunk, dividing R (0, R
  or a non-divisor = one call). A chunk's activations fit in the CPU's cache, and the backward
  pass recomputes them instead of reading them back from memory: about a third more FLOPs for
  less memory traffic. The density noise of chunk c is drawn from fold_in(key, c).
  Returns rgb float32 [R, S, 3], sigma float32 [R, S], equal to `query`'s up to rounding.
  """
  num_rays = points.shape[0]
  if not chunk or chunk >= num_rays or num_rays % chunk or points.ndim != 3:
    return query(model, params, points, viewdirs, config, key)
  count = num_rays // chunk
  split = lambda a: a.reshape(count, chunk, *a.shape[1:])

  @jax.checkpoint
  def one_chunk(args):
    pts, dirs, index = args
    chunk_key = None if key is None else jax.random.fold_in(key, index)
    return query(model, params, pts, dirs, config, chunk_key)

  rgb, sigma = jax.lax.map(one_chunk, (split(points), split(viewdirs), jnp.arange(count)))
  return rgb.reshape(*points.shape[:-1], 3), sigma.reshape(points.shape[:-1])


def coarse_density(model, params, config):
  """points float32 [P, 3] -> σ float32 [P] of the coarse network (direction-independent)."""
  def density(points):
    _, sigma = query(model, params["coarse"], points[:, None, :], jnp.zeros_like(points), config)
    return sigma[:, 0]
  return density
