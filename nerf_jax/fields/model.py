"""The radiance-field MLP (the only module that imports flax.linen).

Inputs are already encoded (see encoding.py):
  pos_features: float32 [..., Dp]  encoded sample positions
  dir_features: float32 [..., Dd]  encoded unit viewing directions (only if view_dependent)
  image:        int32 [...] or None  training image of each ray (pos_features: [..., S, Dp]),
                for the per-image appearance code (appearance_dims > 0); None = the mean code
The networks are built from config.model by experiment.make_field: its encoding's subsection
(model.grid or model.hash) unpacked into the module's fields.
Outputs:
  rgb:       float32 [..., 3]  colour in (0, 1) (sigmoid)
  raw_sigma: float32 [...]     density before its activation (renderer.py adds noise, activates)
"""

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from nerf_jax.backend import precision
from nerf_jax.fields.encodings import grid, hashgrid, tensorf


def _appearance_codes(module, image, shape):
  """Per-training-image appearance codes (GLO, as NeRF-W and nerfacto): `module`'s parameter
  'appearance', a table float32 [appearance_images, appearance_dims] (zeros at the start).
  Returns codes [*shape[:-1], dims] for rays' images int32 [...] (shape = the features'
  [..., S, F]: each ray's code goes to all its samples), or the mean code for image None.
  A code conditions colour only, never density."""
  table = module.param("appearance", nn.initializers.zeros,
                       (module.appearance_images, module.appearance_dims))
  code = jnp.mean(table, axis=0) if image is None else table[image][..., None, :]
  return jnp.broadcast_to(code, (*shape[:-1], module.appearance_dims))


def _dense(network, features, name):
  """A Dense layer of `network` (inside its compact call): float32 parameters, the network's
  matmul dtype and float32 matmul precision (its `dtype` and `matmul_precision` fields)."""
  return nn.Dense(features, dtype=jnp.dtype(network.dtype), param_dtype=jnp.float32, name=name,
                  precision=precision.network_precision(network.matmul_precision))


class NerfMLP(nn.Module):
  """NeRF's MLP: `depth` ReLU layers of `width` with the input re-injected after `skip_layers`.

  view_dependent=False is the reference's position-only model (one linear head of 4 outputs).
  view_dependent=True is the paper's 5D model: density from position only; colour from a `width`
  feature plus the encoded direction through one ReLU layer of `view_width`.
  dtype is the matmul dtype (float32, bfloat16 or float16); parameters stay float32 and the
  outputs are cast back to float32 so compositing is always done in float32. matmul_precision
  is the float32 matmuls' precision (nerf_jax.backend.precision: 'default' is TF32 on recent GPUs).
  """
  depth: int = 8
  width: int = 256
  skip_layers: Sequence[int] = (4,)
  view_dependent: bool = False
  view_width: int = 128
  dtype: str = "float32"
  matmul_precision: str = "default"  # precision.NETWORK_PRECISIONS: 'default', 'high', 'highest'
  appearance_images: int = 1
  appearance_dims: int = 0

  @nn.compact
  def __call__(self, pos_features, dir_features=None, image=None):
    x = pos_features.astype(jnp.dtype(self.dtype))
    inputs = x
    for i in range(self.depth):
      x = nn.relu(_dense(self, self.width, f"layer_{i}")(x))
      if i in self.skip_layers:
        x = jnp.concatenate([x, inputs], axis=-1)
    if not self.view_dependent:
      if not self.appearance_dims:
        out = _dense(self, 4, "output")(x).astype(jnp.float32)
        return nn.sigmoid(out[..., :3]), out[..., 3]
      # The reference's head split in two: density from x alone, colour from x and the code.
      raw_sigma = _dense(self, 1, "sigma")(x)[..., 0].astype(jnp.float32)
      code = _appearance_codes(self, image, x.shape).astype(x.dtype)
      rgb = _dense(self, 3, "rgb")(jnp.concatenate([x, code], axis=-1)).astype(jnp.float32)
      return nn.sigmoid(rgb), raw_sigma
    raw_sigma = _dense(self, 1, "sigma")(x)[..., 0].astype(jnp.float32)
    feature = _dense(self, self.width, "feature")(x)
    extra = [dir_features]
    if self.appearance_dims:  # the code joins the direction in the colour branch
      extra.append(_appearance_codes(self, image, feature.shape))
    h = jnp.concatenate([feature, *(e.astype(feature.dtype) for e in extra)], axis=-1)
    h = nn.relu(_dense(self, self.view_width, "view")(h))
    rgb = _dense(self, 3, "rgb")(h).astype(jnp.float32)
    return nn.sigmoid(rgb), raw_sigma


class _GridHead(nn.Module):
  """The tiny MLP of the grid fields: grid features float [..., F] at unit-cube positions
  float32 [..., 3] (and encoded directions) -> (rgb float32 [..., 3], raw_sigma float32 [...])."""
  hidden: int = 64
  view_dependent: bool = False
  view_width: int = 32
  dtype: str = "float32"
  appearance_images: int = 1
  appearance_dims: int = 0
  cell_aspect: Sequence[float] = (1.0, 1.0, 1.0)  # relative x, y, z sides of a lattice cell
  matmul_precision: str = "default"  # precision.NETWORK_PRECISIONS: 'default', 'high', 'highest'

  def _unit(self, points):
    """Positions float32 [..., 3] in the grids' unit cube: of `box` if set, else of the cube."""
    if not self.box:
      return grid.to_unit_cube(points, self.bound)
    return grid.to_unit_box(points, (self.box[:3], self.box[3:]))

  def _shape(self, resolution):
    """Lattice points per axis of a level with `resolution` along the axis with most cells."""
    box = (self.box[:3], self.box[3:]) if self.box else ((-self.bound,) * 3, (self.bound,) * 3)
    return grid.axis_resolutions(resolution, box, self.cell_aspect)

  def _head(self, h, unit, dir_features, image=None):
    """Density and a feature from one hidden layer, colour from the feature (and direction,
    and appearance code)."""
    h = nn.relu(_dense(self, self.hidden, "hidden")(h))
    raw_sigma = _dense(self, 1, "sigma")(h)[..., 0].astype(jnp.float32)
    raw_sigma = jnp.where(grid.inside_box(unit), raw_sigma, -1e5)
    extra = [dir_features] if self.view_dependent else []
    if self.appearance_dims:  # colour only: the code joins h after density is taken from it
      extra.append(_appearance_codes(self, image, h.shape))
    if extra:
      h = jnp.concatenate([h, *(e.astype(h.dtype) for e in extra)], axis=-1)
    if self.view_dependent:
      h = nn.relu(_dense(self, self.view_width, "view")(h))
    rgb = _dense(self, 3, "rgb")(h).astype(jnp.float32)
    return nn.sigmoid(rgb), raw_sigma

  @property
  def num_levels(self):
    """Resolution levels of the encoding, coarsest first (their features are concatenated)."""
    return len(self.resolutions)


def weigh_levels(h, level_weights):
  """Features float [..., L·F] of L equal-width levels, level l scaled by level_weights[l]
  (float32 [L]; None = unchanged): BARF's coarse-to-fine window over a grid's levels."""
  if level_weights is None:
    return h
  levels = level_weights.shape[0]
  scaled = h.reshape(*h.shape[:-1], levels, -1) * level_weights[:, None].astype(h.dtype)
  return scaled.reshape(h.shape)


class GridNeRF(_GridHead):
  """The fast field: multiresolution dense feature grids over the scene box + a tiny MLP.

  Takes raw world positions `points: float32 [..., 3]` (no positional encoding: the grids are
  the encoding) and optionally encoded directions. Density and a feature come from one hidden
  layer over the concatenated grid features; colour from the feature (and direction).
  Positions outside the box get raw density -1e5, which every density activation maps to 0
  with a zero gradient (relu, softplus and exp all underflow to exactly 0 there).
  level_weights (GridNeRF, HashNeRF, TensoRFNeRF): float32 [num_levels] or None, each level's
  features scaled by its weight (`weigh_levels`: pose refinement's coarse to fine).
  """
  resolutions: Sequence[int] = (32, 64, 128)
  features: int = 4
  bound: float = 1.5
  box: Sequence[float] = ()  # (min x, y, z, max x, y, z) of a tighter box; () = the bound's cube

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None):
    init = lambda key, shape: 1e-2 * jax.random.normal(key, shape, jnp.float32)
    grids = [self.param(f"grid_{r}", init, (*self._shape(r), self.features))
             for r in self.resolutions]
    unit = self._unit(points.astype(jnp.float32))
    h = weigh_levels(grid.multires_features(grids, unit), level_weights)
    return self._head(h.astype(jnp.dtype(self.dtype)), unit, dir_features, image)


class HashNeRF(_GridHead):
  """GridNeRF with a multiresolution hash grid (hashgrid.py) in place of the dense grids.

  The same inputs, outputs, head and out-of-box density as GridNeRF; the table holds the
  `levels` levels' rows, initialised uniform in ±1e-4 as in instant-ngp (the MLP starts from a
  nearly constant field, and no level dominates before training).
  gather_dtype: dtype of the gathered corner rows (the table stays float32, see hashgrid.encode).
  """
  levels: int = 16
  log2_size: int = 19
  features: int = 2
  base_resolution: int = 16
  max_resolution: int = 2048
  gather_dtype: str = "float32"
  bound: float = 1.5
  box: Sequence[float] = ()  # as GridNeRF's

  @property
  def num_levels(self):
    return self.levels

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None):
    resolutions = hashgrid.level_resolutions(self.levels, self.base_resolution,
                                             self.max_resolution)
    rows = sum(hashgrid.level_rows(resolutions, self.log2_size))
    init = lambda key, shape: jax.random.uniform(key, shape, jnp.float32, -1e-4, 1e-4)
    table = self.param("hash_table", init, (rows, self.features))
    unit = self._unit(points.astype(jnp.float32))
    h = hashgrid.encode(table, unit, resolutions, self.log2_size, self.gather_dtype)
    h = weigh_levels(h, level_weights)
    return self._head(h.astype(jnp.dtype(self.dtype)), unit, dir_features, image)


class TensoRFNeRF(_GridHead):
  """GridNeRF with vector-matrix factorised fields (tensorf.py) in place of the dense grids.

  The same inputs, outputs, head and out-of-box density as GridNeRF. Each level is a TensoRF-VM
  field with `rank` components per mode and `resolution` lattice points along the box's longest
  side (3·rank features); the levels' features are concatenated. Planes and lines start at
  0.1·N(0, 1), so their products, the features, start at about GridNeRF's 1e-2.
  """
  resolutions: Sequence[int] = (128, 256)
  rank: int = 16
  bound: float = 1.5
  box: Sequence[float] = ()  # as GridNeRF's

  @nn.compact
  def __call__(self, points, dir_features=None, image=None, level_weights=None):
    init = lambda key, shape: 0.1 * jax.random.normal(key, shape, jnp.float32)
    unit = self._unit(points.astype(jnp.float32))
    features = []
    for r in self.resolutions:
      plane_shapes, line_shapes = tensorf.shapes(self._shape(r), self.rank)
      planes = [self.param(f"plane_{r}_{m}", init, s) for m, s in enumerate(plane_shapes)]
      lines = [self.param(f"line_{r}_{m}", init, s) for m, s in enumerate(line_shapes)]
      features.append(tensorf.vm_features(planes, lines, unit))
    h = weigh_levels(jnp.concatenate(features, axis=-1), level_weights)
    return self._head(h.astype(jnp.dtype(self.dtype)), unit, dir_features, image)


class DensityGridNeRF(_GridHead):
  """GridNeRF with density read straight from grids of its own (DVGO's recipe): the raw density
  is interpolated, then activated (by the Field), so it stays sharp inside a cell; it is the sum
  of one-channel grids at several resolutions, so coarse shapes form in few steps and fine ones
  on top. Colour comes from the feature grids and the tiny MLP as in GridNeRF.

  The two halves can be evaluated alone (`part`): the density of every sample is a single
  trilinear read, and the renderer computes colour only where the weights say it matters
  (renderer.RayRenderer.colour_fraction). The density grid starts at raw INITIAL_RAW_DENSITY
  everywhere: a faint haze (DVGO's low initial opacity), so no early floaters block the rays,
  yet dense enough that the colour MLP's first gradients come from the surfaces.
  part: 'all' -> (rgb, raw_sigma); 'density' -> raw_sigma; 'colour' -> rgb.
  """
  resolutions: Sequence[int] = (32, 64, 128)
  features: int = 4
  bound: float = 1.5
  box: Sequence[float] = ()  # as GridNeRF's
  density_resolutions: Sequence[int] = (32, 64, 128)  # lattice points per side of each level
  density_hash_resolution: int = 0  # a finer, hashed density level: points per side (0 = none)
  density_hash_log2_size: int = 20  # log2 of its table's rows
  colour_hash_resolution: int = 0  # a finer, hashed colour feature level: points per side
  colour_hash_log2_size: int = 20  # log2 of its table's rows

  def _raw_density(self, unit):
    """Raw density float32 [...] at unit-box positions float32 [..., 3]: the sum of the dense
    levels and, if set, the hashed level (instant-ngp's hash: its rows cost memory and Adam's
    update in proportion to 2^log2_size, not to its resolution cubed)."""
    hashed = bool(self.density_hash_resolution)
    start = INITIAL_RAW_DENSITY / DENSITY_GAIN / (len(self.density_resolutions) + hashed)
    levels = [self.param(f"density_{r}", nn.initializers.constant(start), (*self._shape(r), 1))
              for r in self.density_resolutions]
    raw = sum(grid.trilinear(g, unit)[..., 0] for g in levels)
    if hashed:
      raw = raw + self._hashed_level("hashed_density", nn.initializers.constant(start), 1, unit,
                                     self.density_hash_resolution,
                                     self.density_hash_log2_size)[..., 0]
    return DENSITY_GAIN * raw

  def _hashed_level(self, name, init, features, unit, resolution, log2_size):
    """Features float32 [..., features] of a one-level hash grid (hashgrid.py) of `resolution`
    points per side in 2^log2_size rows (fewer if its lattice fits), the parameter `name`."""
    rows = hashgrid.level_rows((resolution,), log2_size)[0]
    table = self.param(name, init, (rows, features))
    return hashgrid.encode(table, unit, (resolution,), log2_size)

  @nn.compact
  def __call__(self, points, dir_features=None, part="all"):
    unit = self._unit(points.astype(jnp.float32))
    raw_sigma = rgb = None
    if part in ("all", "density"):
      raw = self._raw_density(unit)
      raw_sigma = jnp.where(grid.inside_box(unit), raw, -1e5)
    if part in ("all", "colour"):
      init = lambda key, shape: 1e-2 * jax.random.normal(key, shape, jnp.float32)
      grids = [self.param(f"grid_{r}", init, (*self._shape(r), self.features))
               for r in self.resolutions]
      h = grid.multires_features(grids, unit)
      if self.colour_hash_resolution:  # read only by the samples that get colour
        fine = self._hashed_level("hashed_colour", init, self.features, unit,
                                  self.colour_hash_resolution, self.colour_hash_log2_size)
        h = jnp.concatenate([h, fine], axis=-1)
      h = nn.relu(_dense(self, self.hidden, "hidden")(h.astype(jnp.dtype(self.dtype))))
      if self.view_dependent:
        h = jnp.concatenate([h, dir_features.astype(h.dtype)], axis=-1)
        h = nn.relu(_dense(self, self.view_width, "view")(h))
      rgb = nn.sigmoid(_dense(self, 3, "rgb")(h).astype(jnp.float32))
    return {"all": (rgb, raw_sigma), "density": raw_sigma, "colour": rgb}[part]


# Parameter names of the grid fields' lattice tables, with their number of spatial axes (the
# last axis holds features): dense grids and density levels, TensoRF's planes and lines.
TABLE_AXES = {"grid_": 3, "density_": 3, "plane_": 2, "line_": 1}


def lattice_tables(params):
  """[(table, spatial axes)] of every lattice table in a network's params (a nested dict)."""
  found = []
  for name, value in params.items():
    if isinstance(value, dict):
      found += lattice_tables(value)
      continue
    for prefix, axes in TABLE_AXES.items():
      if name.startswith(prefix):
        found.append((value, axes))
  return found


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
