"""Multiresolution hash-grid encoding (instant-ngp, Müller et al. 2022): config name 'hash',
settings config.model.hash (`Settings`), read by the lattice head unless model.network says.

Names:
  unit:   float32 [..., 3]  positions in [0, 1]^3 (grid.to_unit_cube); outside is clamped
  table:  float32 [rows, F] the feature rows of every level, one level after the other
  L levels; level l has R_l lattice points per side (grid.py's convention: R_l - 1 cells over
  [0, 1]), R_l growing geometrically from the base to the finest resolution.
Level l owns min(R_l^3, T) rows, T = 2^log2_size. A level whose lattice fits in T rows is indexed
densely, (i·R + j)·R + k: the layout of a grid.py grid [R, R, R, F] reshaped, with no collisions.
Finer levels share their T rows through instant-ngp's spatial hash; the MLP after the encoding
and the coarser, collision-free levels disambiguate the collisions. Each level interpolates its 8
corner rows trilinearly; the L levels' features are concatenated, [..., L·F]. The cost per
sample is independent of T: one gather of 8·L rows (its gradient: a scatter-add of 8·L rows).
"""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.backend import components, draws
from nerf_jax.fields import registry
from nerf_jax.fields.encodings import grid

# instant-ngp's primes, one per axis; the first is 1 so neighbouring x share cache lines.
PRIMES = (1, 2654435761, 805459861)
DTYPES = ("float32", "float16", "bfloat16")


def level_resolutions(num_levels, base, finest):
  """Lattice points per side of each level: a tuple of `num_levels` ints from base to finest.

  R_l = round(base · (finest / base)^(l / (L - 1))), a geometric progression (a single level
  is just `base`).
  """
  if num_levels < 1 or base < 2 or finest < base:
    raise ValueError(f"hash grid: need model.hash.levels >= 1 and 2 <= "
                     f"model.hash.base_resolution <= model.hash.max_resolution, got "
                     f"{num_levels}, {base}, {finest}")
  if num_levels == 1:
    return (int(base),)
  growth = (finest / base) ** (np.arange(num_levels) / (num_levels - 1))
  return tuple(int(r) for r in np.round(base * growth))


def level_rows(resolutions, log2_size):
  """Rows of each level's table: min(R^3, 2^log2_size), a tuple of ints."""
  if not 1 <= log2_size <= 24:
    raise ValueError(f"model.hash.log2_size must be in [1, 24] (2^24 rows per level), got "
                     f"{log2_size}")
  return tuple(min(r ** 3, 2 ** log2_size) for r in resolutions)


def spatial_hash(corner, log2_size):
  """instant-ngp's spatial hash: (x·1 XOR y·2654435761 XOR z·805459861) mod 2^log2_size.

  corner: int [..., 3] non-negative lattice coordinates. Returns uint32 [...]. The products are
  meant to wrap modulo 2^32 (as in the CUDA original): in uint32, XLA's integer multiply wraps,
  whereas in int32 a wrapped product would be negative and the modulo would go wrong.
  """
  c = corner.astype(jnp.uint32)
  primes = jnp.asarray(PRIMES, jnp.uint32)
  h = (c[..., 0] * primes[0]) ^ (c[..., 1] * primes[1]) ^ (c[..., 2] * primes[2])
  return h & jnp.uint32(2 ** log2_size - 1)  # the table size is a power of two


def _corners(unit, resolutions):
  """Lower lattice corner and in-cell fraction of each level.

  Returns lower: int32 [..., L, 3] and frac: float32 [..., L, 3] in [0, 1]; as grid.trilinear
  (positions clamped to the box; floor clamped to R - 2 so the upper corner exists at x = R - 1).
  """
  res = np.asarray(resolutions, np.float32)[:, None]  # [L, 1]
  x = jnp.clip(unit, 0.0, 1.0)[..., None, :] * (res - 1)
  lower = jnp.clip(jnp.floor(x), 0, res - 2)
  return lower.astype(jnp.int32), x - lower


_OFFSETS = np.array([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)], np.int32)  # [8, 3]


def corner_rows(unit, resolutions, log2_size):
  """Rows of the concatenated table and trilinear weights of each level's 8 corners.

  unit: float32 [..., 3]. Returns rows: int32 [..., L, 8] (offset into the level's block) and
  weights: float32 [..., L, 8], each level's weights summing to 1.
  """
  lower, frac = _corners(unit, resolutions)
  corner = lower[..., None, :] + _OFFSETS  # [..., L, 8, 3]
  res = np.asarray(resolutions, np.uint32)[:, None]  # [L, 1]
  c = corner.astype(jnp.uint32)
  # Wraps for hashed levels (R^3 >= 2^32 possible), but there it is discarded by the `where`.
  dense = (c[..., 0] * res + c[..., 1]) * res + c[..., 2]
  rows = level_rows(resolutions, log2_size)
  is_dense = np.array([n == r ** 3 for n, r in zip(rows, resolutions)])[:, None]  # [L, 1]
  index = jnp.where(is_dense, dense, spatial_hash(corner, log2_size))
  offsets = np.cumsum((0,) + rows[:-1]).astype(np.int32)[:, None]  # [L, 1]
  weights = jnp.prod(jnp.where(_OFFSETS == 1, frac[..., None, :], 1.0 - frac[..., None, :]),
                     axis=-1)
  return index.astype(jnp.int32) + offsets, weights


def _interpolate(table, rows, weights, dtype):
  """Sum of the gathered rows table[rows]: [..., L, 8, F] times weights [..., L, 8], in dtype."""
  corners = table[rows].astype(dtype)
  return jnp.sum(weights.astype(dtype)[..., None] * corners, axis=-2)


@functools.partial(jax.custom_vjp, nondiff_argnums=(3,))
def _interpolate_low(table, rows, weights, dtype):
  """`_interpolate` in a low dtype, returned as float32, whose gradient is computed in float32.

  Plain autodiff would carry the cotangent back through the casts in float16, where the small
  cotangents of a mean loss (1e-5 to 1e-8 per row) are subnormal or flushed to zero: measured on
  tests/fields/encodings/test_hash.py's float16 case,
  53 of 6060 non-zero table gradients became exactly 0.
  """
  return _interpolate(table, rows, weights, dtype).astype(jnp.float32)


def _interpolate_low_fwd(table, rows, weights, dtype):
  return _interpolate_low(table, rows, weights, dtype), (table, rows, weights)


def _interpolate_low_bwd(dtype, residuals, g):
  table, rows, weights = residuals
  d_table = jnp.zeros_like(table).at[rows].add(weights[..., None] * g[..., None, :])
  d_weights = jnp.sum(table[rows] * g[..., None, :], axis=-1)
  return d_table, None, d_weights


_interpolate_low.defvjp(_interpolate_low_fwd, _interpolate_low_bwd)


def encode(table, unit, resolutions, log2_size, dtype="float32"):
  """The hash-grid features of positions: float32 [..., L·F].

  table: float32 [sum(level_rows), F]. unit: float32 [..., 3].
  dtype: the dtype the gathered corner rows are cast to and interpolated in. The table itself
  (the parameters, so Adam's moments and updates) stays float32: stored in float16, an update of
  lr · 1e-3 to an entry of order 1e-4 (the initial scale) would round away (float16 is subnormal
  below 6e-5), and Adam's second moment g^2 of a rarely-hit row would underflow to 0, leaving
  the update m / (sqrt(v) + eps) to divide by an eps that is itself 0 in float16. The gradient
  is computed in float32 (see `_interpolate_low`). So float16 halves only the gathered
  [..., L, 8, F] rows and the interpolation arithmetic, not the table's memory or traffic.
  """
  if dtype not in DTYPES:
    raise ValueError(f"model.hash.gather_dtype must be one of {DTYPES}, got {dtype!r}")
  rows, weights = corner_rows(unit, resolutions, log2_size)
  if dtype == "float32":
    features = _interpolate(table, rows, weights, jnp.float32)  # [..., L, F]
  else:
    features = _interpolate_low(table, rows, weights, jnp.dtype(dtype))
  return features.reshape(*features.shape[:-2], -1)


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model.hash."""
  levels: int = 16  # resolution levels
  log2_size: int = 19  # log2 of the rows of each level's table
  features: int = 2  # features per row
  base_resolution: int = 16  # lattice points per side of the coarsest level
  max_resolution: int = 2048  # lattice points per side of the finest level
  gather_dtype: str = "float32"  # dtype of the gathered rows (the table stays float32)
  antialias: bool = False  # Zip-NeRF: 6 points per frustum, levels weighted by its scale
  multisample: bool = True  # with antialias: the 6 points (False: the frustum's mean alone)

  def __post_init__(self):
    level_rows(self.resolutions, self.log2_size)  # ValueErrors naming the fields
    if self.gather_dtype not in DTYPES:
      raise ValueError(f"model.hash.gather_dtype must be one of {DTYPES}, got "
                       f"{self.gather_dtype!r}")

  @property
  def resolutions(self):
    """Lattice points per side of each level (`level_resolutions`)."""
    return level_resolutions(self.levels, self.base_resolution, self.max_resolution)


@dataclasses.dataclass(frozen=True)
class HashGrid:
  """The hash grid of `settings` over `space` (protocol.Encoding): one parameter 'hash_table'
  float32 [sum(level_rows), features] holding every level's rows, initialised uniform in ±1e-4
  as in instant-ngp (the network starts from a nearly constant field, and no level dominates
  before training)."""
  settings: Settings
  space: grid.Space

  @property
  def coarse_to_fine_stages(self):
    return max(self.settings.levels - 1, 0)

  def band_weights(self, bands):
    return grid.level_window(bands, self.coarse_to_fine_stages)

  def features(self, module, points, weights=None, multisamples=None):
    """float32 [..., levels·features] at world positions float32 [..., 3] (clamped to the box
    outside it), level l scaled by weights[l]; the table is `module`'s parameter.
    multisamples: None, or Zip-NeRF's (points float32 [..., M, 3], std float32 [..., M]) of
    each frustum (settings.antialias; M = 6, or 1 without multisample): their features, grid.antialiased, instead of points'."""
    s = self.settings
    rows = sum(level_rows(s.resolutions, s.log2_size))
    init = lambda key, shape: draws.uniform(key, shape, jnp.float32, -1e-4, 1e-4)
    table = module.param("hash_table", init, (rows, s.features))
    if multisamples is None:
      h = encode(table, self.space.unit(points), s.resolutions, s.log2_size, s.gather_dtype)
      return grid.weigh_levels(h, weights)
    six, std = multisamples
    h = encode(table, self.space.unit(six), s.resolutions, s.log2_size, s.gather_dtype)
    levels = h.reshape(*h.shape[:-1], s.levels, s.features)  # [..., M, L, F]
    cells = self.space.cell_sizes(s.resolutions)
    return grid.weigh_levels(grid.antialiased(levels, std, cells), weights)

  def inside(self, points):
    return self.space.inside(points)

  def width(self, dim):
    del dim
    return self.settings.levels * self.settings.features


def build(settings, shared):
  """The HashGrid of `settings` over the space of `shared` (protocol.NetworkSettings)."""
  return HashGrid(settings, grid.Space.of(shared))


def signature(settings):
  """The table's shape and the meaning of its rows (the gathered dtype changes neither)."""
  entries = {"encoding": "hash",
             **components.signature(settings, "hash_", exclude=("gather_dtype", "antialias", "multisample"))}
  if settings.antialias:  # only when on: checkpoints saved before it keep restoring
    entries["hash_antialias"] = True if settings.multisample else "scales"
  return entries


ENCODING = registry.Encoding("hash", Settings, build, signature, network="lattice",
                             records_grid_section=True,
                             cones=grid.cone_kind)
