"""What a field's network is: the calling convention between a Field (field.py) and the Flax
module of an encoding family (registry.py), and the settings every family's network shares.

A network is applied as

  network.apply({'params': p}, positions, dir_features[, image][, level_weights=w])
      -> (rgb float32 [..., S, 3] in (0, 1), raw_sigma float32 [..., S])

  positions:     float32 [..., S, P]  world (or contracted) positions, P = 3, for a family with
                 raw_positions; else their positional encoding (encodings/encoding.py)
  dir_features:  float32 [..., S, D] or None  encoded unit viewing directions (view_dependent)
  image:         int32 [...]  each ray's training image, passed only with appearance_dims > 0
                 (its appearance code; None = the mean code, as for held-out views)
  level_weights: float32 [num_levels]  passed only while poses are refined (BARF's coarse to
                 fine window over the levels, see Field.level_weights), to a network with levels

raw_sigma is density before its activation (the Field adds noise and activates it). A network
whose `splits_density` is True also takes `part='density'` (positions alone -> raw_sigma) and
`part='colour'` (positions, dir_features -> rgb).
"""

import dataclasses
from typing import Any, Protocol, Sequence, runtime_checkable


@runtime_checkable
class Network(Protocol):
  """The Flax module of a field (see the module docstring for its call)."""

  @property
  def num_levels(self) -> int:
    """Resolution levels the network weighs by `level_weights`, coarsest first (0: none)."""

  @property
  def splits_density(self) -> bool:
    """Whether density and colour can be evaluated alone (`part`, module docstring)."""

  def init(self, rngs: Any, *args, **kwargs) -> Any:
    """Flax's init."""

  def apply(self, variables: Any, *args, **kwargs) -> Any:
    """Flax's apply."""


@dataclasses.dataclass(frozen=True)
class NetworkSettings:
  """What every family's network may take besides its own section (config.model's shared
  fields), built once by run/experiment.py. A family uses the ones that apply to it."""
  view_dependent: bool = False  # colour takes the encoded viewing direction
  view_width: int = 128  # width of the colour branch's layers after the direction joins
  view_depth: int = 1  # how many such layers
  hidden: int = 256  # width of the hidden layers (the MLP's, or a grid head's)
  dtype: str = "float32"  # matmul dtype of the layers (parameters stay float32)
  matmul_precision: str = "default"  # backend.precision.NETWORK_PRECISIONS
  appearance_images: int = 1  # rows of the appearance codes' table (training images)
  appearance_dims: int = 0  # length of each image's appearance code (0 = none)
  density_activation: str = "relu"  # the Field's density activation (activations.py)
  bound: float = 1.5  # a grid network's grids cover [-bound, bound]^3 ...
  box: Sequence[float] = ()  # ... or this (min x, y, z, max x, y, z) box when set
  cell_aspect: Sequence[float] = (1.0, 1.0, 1.0)  # relative x, y, z sides of a lattice cell

  @property
  def head(self):
    """The keyword arguments of the shared head fields of every built-in network."""
    kwargs = dict(view_dependent=self.view_dependent, view_width=self.view_width,
                  dtype=self.dtype, matmul_precision=self.matmul_precision)
    if self.view_depth != 1:  # only then, so a network of its own need not know the field
      kwargs.update(view_depth=self.view_depth)
    if self.appearance_dims:  # only then, so the networks of runs without codes stay as they were
      kwargs.update(appearance_images=self.appearance_images,
                    appearance_dims=self.appearance_dims)
    return kwargs

  @property
  def space(self):
    """The keyword arguments of a grid network's space and head width."""
    return dict(bound=self.bound, box=tuple(self.box), hidden=self.hidden,
                cell_aspect=tuple(self.cell_aspect))
