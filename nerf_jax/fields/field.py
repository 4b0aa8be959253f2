"""The radiance field: a network's parameters and its queries at sample points.

A field maps points float32 [..., S, 3] and unit view directions float32 [..., 3] to colour
rgb float32 [..., S, 3] and density sigma float32 [..., S] (per unit of world length). It wraps
a Flax network (networks/; protocol.py: the calling convention), which applies its position
encoding (encodings/) to the points, with the encoding of the viewing directions and the
density activation (activations.py).
`Field` is built once (run/builders.make_field) and queried as field.query(params, points,
viewdirs, key). Two optional per-query inputs: `image`, int32 [...] the training image of each
ray, selects its appearance code (appearance_dims > 0; None = the mean code, as for held-out
views), and `bands`, float32 [], how many positional-encoding bands, or grid levels after the
coarsest, are open (BARF's coarse-to-fine α while poses are refined; None = all, as after
training).
A field whose encoding reads cones (`cones`, from Rays.radii) is queried at the means of its
samples' frustums with what the encoding reads of them, `per_sample` (`cone_inputs`): their
Gaussians' diagonal variances (mip-NeRF's integrated encoding; contracted from the full
covariance, as mip-NeRF 360's), or Zip-NeRF's six points and their scales (antialiased
lattices; turned at random while training, with a key). Queried without them (the occupancy
grid's, marching's and the viewer's probes: points with no interval) it sees points: variance 0,
which is the point encoding exactly.
"""

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from nerf_jax.backend import draws
from nerf_jax.cameras import cones
from nerf_jax.cameras.scene_settings import SceneSettings
from nerf_jax.fields import activations, contraction
from nerf_jax.fields.encodings import posenc
from nerf_jax.fields.protocol import NetworkSettings


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model's fields of the Field itself (its parts' are theirs)."""
  density_noise: float = 0.0  # std of noise added to raw density while training (paper: 1)


@dataclasses.dataclass(frozen=True)
class Field:
  """A network and how its inputs and outputs are treated.

  network: the Flax module (protocol.Network: a network of networks/ over its position
    encoding), applied to the points.
  directions: the encoding of the viewing directions (protocol.Encoding: encodings/posenc's
    Frequency, encodings/sh'), read when view_dependent.
  view_dependent: colour takes the encoded viewing direction.
  density_activation: 'relu', 'softplus' or 'exp' (activations.py). density_noise: std of the
    noise added to raw density when a query has a key (training only).
  contraction: '' (world positions), or 'l2' / 'linf': positions are contracted about the inner
    region of half-size `inner_radius` first (contraction.py), so the network sees all of space
    inside [-2·inner_radius, 2·inner_radius]^3.
  cones: what the position encoding reads of each sample's frustum (registry.Encoding.cones):
    '' points, 'gaussians', 'multisamples' or 'scales' (`cone_inputs`); rays then need their
    radii.
  """
  network: Any
  directions: Any = posenc.Frequency(4)
  # Defaults: the settings' (declared once).
  view_dependent: bool = NetworkSettings.view_dependent
  density_activation: str = NetworkSettings.density_activation
  density_noise: float = Settings.density_noise
  contraction: str = SceneSettings.contraction
  inner_radius: float = 1.0
  appearance_dims: int = NetworkSettings.appearance_dims
  cones: str = ""

  @property
  def uses_images(self):
    """Whether a query takes each ray's training image (its appearance code)."""
    return self.appearance_dims > 0

  def init(self, key):
    """The network's parameters, from PRNG key `key`."""
    pos = jnp.zeros((1, 3), jnp.float32)
    dirs = jnp.zeros((1, self.dir_width), jnp.float32)
    # Compiled as one program: run op by op, a grid network's init compiled ~100 small programs
    # (~8 s on 2 cores); the values are the same (draws.normal_init).
    return jax.jit(self.network.init)(key, pos, dirs)["params"]

  @property
  def dir_width(self):
    """Features of `encode_directions`."""
    return self.directions.width(3)

  def encode_directions(self, dirs):
    """The network's direction input for unit directions float32 [..., 3]: float32
    [..., dir_width]."""
    return self.directions.features(None, dirs)

  @property
  def coarse_to_fine_stages(self):
    """What opens coarse to fine while poses are refined (the most `bands` means): the
    position encoding's bands, or a lattice's levels after the coarsest (always open); 0 for a
    network that opens nothing (protocol.Network.coarse_to_fine_stages)."""
    return self.network.coarse_to_fine_stages

  def level_weights(self, bands):
    """The network's level_weights with `bands` open (None: all open, or nothing to open)."""
    if bands is None or not self.coarse_to_fine_stages:
      return None
    return self.network.band_weights(bands)

  def network_points(self, points):
    """The points the network takes for points float32 [..., 3]: contracted first in an
    unbounded scene (the network encodes them)."""
    if self.contraction:
      points = contraction.contract(points, self.inner_radius, self.contraction)
    return points

  def gaussians(self, rays, t0, t1):
    """The Gaussians of the frustums [t0, t1) of `rays` [...] (with radii): (mean float32
    [..., S, 3] in world space, var float32 [..., S, 3] the covariances' diagonals in the
    network's space: in an unbounded scene the diagonal of J Σ Jᵀ, the full covariance Σ
    through the contraction's Jacobian J at the mean, as mip-NeRF 360's
    (contraction.contract_frustum_gaussian)). t0, t1: float32 [..., S]. Query
    `query(params, mean, ..., var=var)`."""
    if rays.radii is None:
      raise ValueError("a field of cones needs rays with radii (pixel_rays(..., with_radii=True))")
    if not self.contraction:
      return cones.frustum_gaussians(rays.origins, rays.directions, rays.radii, t0, t1,
                                     diagonal=True)
    mean, t_var, r_var = cones.frustum_spreads(rays.origins, rays.directions, rays.radii, t0, t1)
    _, var = contraction.contract_frustum_gaussian(mean, rays.directions[..., None, :], t_var,
                                                   r_var, self.inner_radius, self.contraction)
    return mean, var

  def multisamples(self, rays, t0, t1, key=None):
    """Zip-NeRF's six points of each frustum [t0, t1) of `rays` [...] (with radii), or its mean
    alone (cones 'scales'), and their scales, in the network's space (contracted by
    contraction.contract_isotropic in an unbounded scene): (float32 [..., S, M, 3], float32
    [..., S, M]), M = 6 or 1; the scales times cones.UNSCENTED_SCALE_MULT, as Zip-NeRF's level
    weights read them. t0, t1: float32 [..., S]. key: None (evaluation: every other hexagon
    mirrored and turned by 30°, the same every time) or a PRNG key (training, Zip-NeRF's
    jitter: each hexagon mirrored at random and turned by a uniform angle; cones.multisamples).
    The mean alone has nothing to turn: 'scales' ignores the key."""
    if rays.radii is None:
      raise ValueError("a field of cones needs rays with radii (pixel_rays(..., with_radii=True))")
    if self.cones == "scales":
      points, std = cones.centre_samples(rays.origins, rays.directions, rays.radii, t0, t1)
    else:
      points, std = cones.multisamples(rays.origins, rays.directions, rays.radii, t0, t1, key)
    std = cones.UNSCENTED_SCALE_MULT * std  # a Python float: std stays float32
    if self.contraction:
      points, std = contraction.contract_isotropic(points, std, self.inner_radius,
                                                   self.contraction)
    return points, std

  def cone_inputs(self, rays, t0, t1, key=None):
    """(points float32 [..., S, 3], per_sample) of the frustums [t0, t1) of `rays` [...]: where
    `query` queries them (their means, world space) and what the encoding reads of them.
    key: PRNG key of the multisamples' random turns while training (`multisamples`), or None
    (deterministic); a Gaussian has nothing random."""
    if self.cones == "gaussians":
      mean, var = self.gaussians(rays, t0, t1)
      return mean, {"var": var}
    t_mean = cones.frustum_moments(t0, t1)[0]
    mean = rays.origins[..., None, :] + rays.directions[..., None, :] * t_mean[..., None]
    return mean, {"multisamples": self.multisamples(rays, t0, t1, key)}

  def query(self, params, points, viewdirs, key=None, image=None, bands=None, per_sample=None):
    """Colour and density at sample points.

    params: the network's parameters. points: float32 [..., S, 3]. viewdirs: float32 [..., 3]
    unit directions. key: PRNG key for the density noise (None = no noise). image, bands: see
    the module docstring (image is ignored without appearance codes). per_sample: None, or
    `cone_inputs`' dict (a field of cones only).
    Returns rgb float32 [..., S, 3], sigma float32 [..., S].
    """
    dir_features = None
    if self.view_dependent:
      # Encoded once per ray, then given to each of its samples: the same values as encoding
      # every sample's copy of the direction, without S times the sines and cosines.
      encoded = self.encode_directions(viewdirs)
      dir_features = jnp.broadcast_to(encoded[..., None, :],
                                      points.shape[:-1] + encoded.shape[-1:])
    args = (self.network_points(points), dir_features)
    if self.uses_images:
      args += (image,)
    weights = self.level_weights(bands)
    kwargs = {} if weights is None else {"level_weights": weights}
    kwargs.update(per_sample or {})
    rgb, raw_sigma = self.network.apply({"params": params}, *args, **kwargs)
    return rgb, self._activate(raw_sigma, key)

  @property
  def splits_density(self):
    """Whether the network gives density and colour separately (protocol.Network)."""
    return self.network.splits_density

  def _activate(self, raw_sigma, key):
    if key is not None and self.density_noise > 0:
      # The paper's regulariser: noise on the raw output, before the activation keeps sigma >= 0.
      raw_sigma = raw_sigma + self.density_noise * draws.normal(key, raw_sigma.shape)
    return activations.density_activation(self.density_activation)(raw_sigma)

  def query_density(self, params, points, key=None, per_sample=None):
    """sigma float32 [...] at points float32 [..., 3]: the density half alone where the network
    has one (`splits_density`), else `query`'s density (direction-independent). per_sample:
    None, or `cone_inputs`' dict for these points (arrays [..., ...])."""
    if not self.splits_density:
      dirs = jnp.zeros(points.shape[:-2] + (3,), points.dtype)
      return self._query(params, points, dirs, key, None, None, per_sample)[1]
    raw = self.network.apply({"params": params}, self.network_points(points), part="density",
                             **(per_sample or {}))
    return self._activate(raw, key)

  def query_colour(self, params, points, viewdirs, per_sample=None, image=None):
    """rgb float32 [P, 3] at points float32 [P, 3] seen along unit directions float32 [P, 3]:
    the colour half alone (needs `splits_density`). per_sample: None, or `cone_inputs`' dict
    for these points (arrays [P, ...]). image: int32 [P], each point's training image (its
    appearance code), or None (the mean code); ignored without appearance codes."""
    dir_features = self.encode_directions(viewdirs) if self.view_dependent else None
    args = (self.network_points(points), dir_features)
    if self.uses_images:
      args += (image,)
    return self.network.apply({"params": params}, *args, part="colour", **(per_sample or {}))

  def query_in_chunks(self, params, points, viewdirs, key=None, chunk=0, image=None,
                      bands=None, per_sample=None):
    """`query` over chunks of `chunk` rays, each rematerialised in the backward pass.

    points: float32 [R, S, 3], viewdirs: float32 [R, 3]. chunk: rays per chunk, dividing R (0,
    R or a non-divisor = one call). A chunk's activations fit in the CPU's cache, and the
    backward pass recomputes them instead of reading them back from memory: about a third more
    FLOPs for less memory traffic. The density noise of chunk c is drawn from fold_in(key, c).
    image: int32 [R] or None; bands: float32 [] or None; per_sample: None or a dict of arrays
    [R, ...] (see `query`).
    Returns rgb float32 [R, S, 3], sigma float32 [R, S], equal to `query`'s up to rounding.
    """
    num_rays = points.shape[0]
    if not self.uses_images:
      image = None
    if not chunk or chunk >= num_rays or num_rays % chunk or points.ndim != 3:
      return self._query(params, points, viewdirs, key, image, bands, per_sample)
    count = num_rays // chunk
    split = lambda a: None if a is None else a.reshape(count, chunk, *a.shape[1:])

    @jax.checkpoint
    def one_chunk(args):
      pts, dirs, index, images, cone = args
      chunk_key = None if key is None else jax.random.fold_in(key, index)
      return self._query(params, pts, dirs, chunk_key, images, bands, cone)

    cone = None if per_sample is None else jax.tree_util.tree_map(split, per_sample)
    rgb, sigma = jax.lax.map(one_chunk, (split(points), split(viewdirs), jnp.arange(count),
                                         split(image), cone))
    return rgb.reshape(*points.shape[:-1], 3), sigma.reshape(points.shape[:-1])

  def _query(self, params, points, viewdirs, key, image, bands, per_sample):
    """`query`, per_sample passed only when given (a Field subclass of points need not take
    it)."""
    if per_sample is None:
      return self.query(params, points, viewdirs, key, image, bands)
    return self.query(params, points, viewdirs, key, image, bands, per_sample)

  def at_points(self, params, points, viewdirs):
    """(rgb float32 [P, 3], sigma float32 [P]) at single points float32 [P, 3], each seen along
    its unit direction viewdirs float32 [P, 3]."""
    rgb, sigma = self.query(params, points[:, None, :], viewdirs)
    return rgb[:, 0], sigma[:, 0]

  def density(self, params):
    """fn: points float32 [P, 3] -> σ float32 [P] (density does not depend on the direction)."""
    return lambda points: self.query_density(params, points[:, None, :])[:, 0]
