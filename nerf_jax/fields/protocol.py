"""The calling conventions of a field's parts: the network (networks/, Flax), the position
encoding it applies (encodings/), the direction encoding the Field applies (encodings/), and the
settings every network shares. The records that find them by name are in registry.py.

A network is applied as

  network.apply({'params': p}, points, dir_features[, image][, level_weights=w][, **per_sample])
      -> (rgb float32 [..., S, 3] in (0, 1), raw_sigma float32 [..., S])

  points:        float32 [..., S, 3]  world (or contracted) positions; the network applies its
                 position encoding to them
  dir_features:  float32 [..., S, D] or None  unit viewing directions through the direction
                 encoding (view_dependent)
  image:         int32 [...]  each ray's training image, passed only with appearance_dims > 0
                 (its appearance code; None = the mean code, as for held-out views)
  level_weights: float32 [...]  passed only while poses are refined: `band_weights(bands)`,
                 BARF's coarse-to-fine window over the encoding's bands or levels
  per_sample:    passed only to a network whose encoding reads cones (registry.Encoding.cones),
                 which hands them on to `encoding.features`: var=float32 [..., S, 3], the
                 diagonal variances of the samples' Gaussians (points are their means), or
                 multisamples=(float32 [..., S, 6, 3], float32 [..., S, 6]), Zip-NeRF's six
                 points of each frustum and their scales; in the network's (contracted) space

raw_sigma is density before its activation (the Field adds noise and activates it). A network
whose `splits_density` is True also takes `part='density'` (points alone -> raw_sigma) and
`part='colour'` (points, dir_features -> rgb).

An encoding (`Encoding`) is a small frozen dataclass of its settings. A network calls it inside
its compact call as `encoding.features(module, points, weights)`, or
`encoding.features(module, means, weights, **per_sample)` for cones; an encoding with tables
creates them on that module (`module.param`), so they sit directly in the network's parameters
under the names checkpoints have always stored ('hash_table', 'grid_32', ...). A direction
encoding is called by the Field with module None (it has no parameters).
"""

import dataclasses
from typing import Any, Protocol, Sequence, runtime_checkable

from nerf_jax.backend import components


class Encoding(Protocol):
  """A position or direction encoding (see the module docstring)."""

  @property
  def coarse_to_fine_stages(self) -> int:
    """How many bands (or levels after the always-open coarsest) open coarse to fine while
    poses are refined; 0: nothing opens."""

  def band_weights(self, bands) -> Any:
    """float32 weights of the bands or levels with `bands` (float32 [], traced) open, as
    `features` takes them."""

  def features(self, module, x, weights=None, **per_sample) -> Any:
    """float [..., F] of coordinates x float32 [..., 3] (points, or unit directions), the bands
    or levels scaled by `weights` (None = all open). module: the Flax module (inside its compact
    call) on which the encoding's parameters live, or None for one without. per_sample: further
    per-sample inputs an encoding of cones takes (registry.Encoding.cones): `var` float32
    [..., 3], the diagonal variances of Gaussians of means x ('ipe'), or `multisamples`
    (points float32 [..., 6, 3], std float32 [..., 6]) ('grid', 'hash' with antialias)."""

  def inside(self, points) -> Any:
    """bool [...]: where points float32 [..., 3] lie inside what the encoding covers (a lattice's
    box; the network gives no density outside), or None: everywhere."""

  def width(self, dim) -> int:
    """Features of `features` for `dim` input channels (None where tables decide: lattices)."""


@runtime_checkable
class Network(Protocol):
  """The Flax module of a field (see the module docstring for its call)."""

  @property
  def coarse_to_fine_stages(self) -> int:
    """Its encoding's (Encoding.coarse_to_fine_stages); 0 for a network that opens nothing."""

  def band_weights(self, bands) -> Any:
    """Its encoding's `band_weights`: what it takes as level_weights."""

  @property
  def splits_density(self) -> bool:
    """Whether density and colour can be evaluated alone (`part`, module docstring)."""

  def init(self, rngs: Any, *args, **kwargs) -> Any:
    """Flax's init."""

  def apply(self, variables: Any, *args, **kwargs) -> Any:
    """Flax's apply."""


@dataclasses.dataclass(frozen=True)
class DirectionSettings:
  """config's top-level fields of the field's direction input (model.view_dependent)."""
  dir_encode_dims: int = 4  # frequency bands for viewing directions, or the degree with 'sh'
  dir_encoding: str = "frequency"  # directions: 'frequency' bands, or 'sh' of that degree


@dataclasses.dataclass(frozen=True)
class NetworkSettings:
  """What every encoding and network may take besides its own section: config.model's shared
  fields, built once by run/builders.network_settings. Each uses the ones that apply to it."""
  view_dependent: bool = False  # colour depends on the viewing direction (paper's 5D input)
  view_width: int = 32  # width of the view-dependent colour layer
  view_depth: int = 1  # colour layers of view_width after the direction joins (instant-ngp: 2)
  width: int = 64  # units per hidden layer (MLP: reference 64, paper 256; the lattice head's)
  dtype: str = "float32"  # matmul dtype: float32, bfloat16 or float16
  matmul_precision: str = "default"  # networks' f32 matmuls: default (TF32 on GPUs), high, highest
  appearance_dims: int = 0  # per-training-image appearance code (GLO) for colour; 0 = off
  density_activation: str = "relu"  # 'relu' (reference), 'softplus' (shifted) or 'exp'
  grid_bound: float = 1.5  # grid and hash encodings: the grids cover [-bound, bound]^3
  grid_box: Sequence[float] = ()  # grid encodings: (min x, y, z, max x, y, z) of a tighter box; () = cube
  grid_cell_aspect: Sequence[float] = (1.0, 1.0, 1.0)  # grid and tensorf: relative x, y, z sides of a cell
  # Rows of the appearance codes' table: the training images (from the data).
  appearance_images: int = components.derived(1)
