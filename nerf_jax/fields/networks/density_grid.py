"""The split lattice network (network 'density_grid', DVGO's recipe): density read straight from
one-channel grids of its own, colour from the dense grid encoding's features through the tiny
head. The grid encoding picks it when config.model.grid.density_resolutions is set; its settings
are that section's (encodings/grid.Settings). See protocol.py for its call.
"""

import flax.linen as nn
import jax.numpy as jnp

from nerf_jax.backend import draws
from nerf_jax.fields import registry
from nerf_jax.fields.encodings import grid
from nerf_jax.fields.encodings import hash as hashgrid
from nerf_jax.fields.networks import heads, lattice


class DensityGridNeRF(lattice.LatticeHead):
  """The lattice head with density read straight from grids of its own: the raw density is
  interpolated, then activated (by the Field), so it stays sharp inside a cell; it is the sum
  of one-channel grids at several resolutions, so coarse shapes form in few steps and fine ones
  on top. Colour comes from the feature grids (`encoding`, a grid.DenseGrid) and the tiny MLP
  (the lattice head's `shared` settings, protocol.NetworkSettings), with a per-image
  appearance code joining the direction where shared.appearance_dims is set (colour only).
  With the grid's antialias (Zip-NeRF) every level, density and colour, dense and hashed, is
  weighted by its cell size against each sample's scale (`multisamples`, Field.cone_inputs).

  The two halves can be evaluated alone (`part`): the density of every sample is a single
  trilinear read, and the renderer computes colour only where the weights say it matters
  (renderer.RayRenderer.colour_fraction). The density grid starts at raw INITIAL_RAW_DENSITY
  everywhere: a faint haze (DVGO's low initial opacity), so no early floaters block the rays,
  yet dense enough that the colour MLP's first gradients come from the surfaces. The density
  levels and the hashed levels are encoding.settings' (density_resolutions...).
  part: 'all' -> (rgb, raw_sigma); 'density' -> raw_sigma; 'colour' -> rgb. image: int32 [...]
  leading the points' axes (each ray's [R] for points [R, S, 3], each point's [P] for [P, 3]),
  or None (the mean code), read only with appearance codes.
  """

  def _raw_density(self, unit, scales=None):
    """Raw density float32 [...] at unit-box positions float32 [..., 3]: the sum of the dense
    levels and, if set, the hashed level (instant-ngp's hash: its rows cost memory and Adam's
    update in proportion to 2^log2_size, not to its resolution cubed). With `scales` (a
    frustum's M multisamples: unit float32 [..., M, 3], scales float32 [..., M], world units),
    each level is read at the M points weighted by Zip-NeRF's weight of its cell size and
    averaged (`_level`)."""
    s, space = self.encoding.settings, self.encoding.space
    hashed = bool(s.density_hash_resolution)
    start = INITIAL_RAW_DENSITY / DENSITY_GAIN / (len(s.density_resolutions) + hashed)
    levels = [self.param(f"density_{r}", nn.initializers.constant(start), (*space.shape(r), 1))
              for r in s.density_resolutions]
    raw = sum(self._level(grid.trilinear(g, unit), r, scales)[..., 0]
              for g, r in zip(levels, s.density_resolutions))
    if hashed:
      fine = self._hashed_level("hashed_density", nn.initializers.constant(start), 1, unit,
                                s.density_hash_resolution, s.density_hash_log2_size)
      raw = raw + self._level(fine, s.density_hash_resolution, scales)[..., 0]
    return DENSITY_GAIN * raw

  def _level(self, features, resolution, scales):
    """One level's features float32 [..., F] at points, or, with `scales` (float32 [..., M]:
    features float32 [..., M, F] at a frustum's M multisamples), their mean weighted by
    Zip-NeRF's weight of the level's cell size against each multisample's scale
    (grid.antialiased): a level whose cells are finer than the frustum fades out, so the raw
    density and colour of a wide frustum come from the coarse levels alone."""
    if scales is None:
      return features
    cells = self.encoding.space.cell_sizes((resolution,))
    return grid.antialiased(features[..., None, :], scales, cells)

  def _hashed_level(self, name, init, features, unit, resolution, log2_size):
    """Features float32 [..., features] of a one-level hash grid (hash.py) of `resolution`
    points per side in 2^log2_size rows (fewer if its lattice fits), the parameter `name`."""
    rows = hashgrid.level_rows((resolution,), log2_size)[0]
    table = self.param(name, init, (rows, features))
    return hashgrid.encode(table, unit, (resolution,), log2_size)

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, part="all", multisamples=None):
    s = self.encoding.settings
    # A frustum (the encoding's antialias) is read at its multisamples, each level weighted by
    # its scale; its mean `points` still says whether it lies inside the box.
    centre = self.encoding.space.unit(points)
    unit = centre if multisamples is None else self.encoding.space.unit(multisamples[0])
    scales = None if multisamples is None else multisamples[1]
    raw_sigma = rgb = None
    if part in ("all", "density"):
      raw = self._raw_density(unit, scales)
      raw_sigma = jnp.where(grid.inside_box(centre), raw, -1e5)
    if part in ("all", "colour"):
      h = self.encoding.features(self, points, None, multisamples)
      if s.colour_hash_resolution:  # read only by the samples that get colour
        fine = self._hashed_level("hashed_colour", draws.normal_init(1e-2), s.features, unit,
                                  s.colour_hash_resolution, s.colour_hash_log2_size)
        h = jnp.concatenate([h, self._level(fine, s.colour_hash_resolution, scales)], axis=-1)
      shared = self.shared
      h = nn.relu(heads.dense(shared, shared.width, "hidden")(h.astype(jnp.dtype(shared.dtype))))
      rgb = heads.colour(self, shared, h, dir_features, image)  # the lattice head's branch
    return {"all": (rgb, raw_sigma), "density": raw_sigma, "colour": rgb}[part]

  coarse_to_fine_stages = 0  # its density grids take no coarse-to-fine window

  def band_weights(self, bands):
    del bands
    return None

  @property
  def splits_density(self):
    return True


# Raw density at start: exp(-2) = 0.14 per scene unit (exp activation; the shifted softplus of
# activations.py gives softplus(-2 - 1) = 0.05), a faint haze (~1/3 opacity across a 3-unit box).
# Not fainter: at -5 (0.7% opacity) the colour's gradient in the first steps is a tiny, one-signed
# pull of the random training backgrounds against the object, which Adam's normalised steps turn
# into full steps; on the built-in `detail` every colour went to black (the sigmoid's flat end)
# in 20 steps and stayed there (18.2 dB at 400 steps; 24.1 at -2; docs/quality_per_second.md).
INITIAL_RAW_DENSITY = -2.0
# The grid stores raw density / DENSITY_GAIN: Adam's steps, about lr in size whatever the
# gradient, move raw density DENSITY_GAIN times faster than the features (DVGO trains its density
# grid with a 10x larger learning rate), so a surface forms in tens of steps, not hundreds.
DENSITY_GAIN = 10.0


def build(encoding, settings, shared):
  """The DensityGridNeRF over the grid encoding `encoding` (protocol.NetworkSettings: shared)."""
  del settings  # its own are the grid encoding's
  if not isinstance(encoding, grid.DenseGrid) or not encoding.settings.density_resolutions:
    raise ValueError("config.model.network='density_grid' reads config.model.grid."
                     "density_resolutions: it needs config.model.encoding='grid' with them set")
  if shared.density_activation == "relu":
    raise ValueError("config.model.grid.density_resolutions needs "
                     "config.model.density_activation 'softplus' or 'exp': the density "
                     "grid starts below zero, where relu has no gradient")
  return DensityGridNeRF(encoding, shared)


NETWORK = registry.Network("density_grid", None, build)
