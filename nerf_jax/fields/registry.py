"""The encodings and networks of a field, found by name (backend/components.Registry).

An encoding is one module of its own (encodings/<name>.py): its pure math, the frozen dataclass
of its settings, and an `ENCODING = registry.Encoding(...)` record saying how to build it, which
network reads it unless config.model.network names one, and what its checkpoints record.
`config.model.encoding` names a position encoding ('posenc', 'ipe', 'grid', 'hash', 'tensorf', one
added with `ENCODINGS.register`, or the dotted path of any module defining ENCODING: big_vision's
"the module path is the registry"); `config.dir_encoding` a direction encoding ('frequency',
'sh': modules defining DIRECTION_ENCODING, the same record). A network is a module of networks/
defining `NETWORK = registry.Network(...)` ('mlp', 'lattice', 'density_grid'). Settings are
their own config section (`Encoding.section_path`), built with components.settings_from, so
adding an encoding is one module plus its config section (docs/extending.md).
"""

import dataclasses
from typing import Any, Callable, Mapping, Union

from nerf_jax.backend import components


def _nothing(settings):
  del settings
  return {}


@dataclasses.dataclass(frozen=True)
class Encoding:
  """A position or direction encoding.

  name: its config name. settings: the frozen dataclass of its settings (each field with its
    default and a one-line comment; validation in __post_init__ raising ValueError naming the
    config field): config.<section_path>'s defaults come from it (components.section).
  build: (settings, protocol.NetworkSettings) -> the encoding (protocol.Encoding), which the
    network applies (a direction encoding: the Field).
  network: the name of the network that reads it when config.model.network is '' ('mlp': NeRF's
    MLP, 'lattice': the grids' tiny head), or settings -> that name.
  signature: settings -> {key: JSON value}, the encoding's entries of the checkpoint signature
    (components.signature: the settings that fix its parameters' shapes and meaning); keep a
    released encoding's keys, so its checkpoints restore.
  table_axes: parameter-name prefixes of its lattice tables -> their spatial axes (the last axis
    holds features): the tables the total variation (loss.total_variation) smooths.
  section: the dotted config path of its settings; None = model.<name>, '' = the top level. A
    shared section ('', 'model') gives only the fields the settings declare.
  records_grid_section: its checkpoints also record config.model.grid's lattice entries (the
    hash and TensoRF encodings' have since they were added, so theirs keep restoring).
  cones: what it encodes of each sample's frustum (cameras/cones.py; the rays then carry their
    radii, Rays.radii), or settings -> that: '' points; 'gaussians' mip-NeRF's Gaussian, the
    Field hands `features` the means with their diagonal variances as `var=`; 'multisamples'
    Zip-NeRF's six points, handed as `multisamples=(points, std)` beside the means; 'scales'
    the same with each frustum's mean as its one point (levels weighted, no multisampling).
  """
  name: str
  settings: type
  build: Callable[[Any, Any], Any]
  network: Union[str, Callable[[Any], str]] = "mlp"
  signature: Callable[[Any], dict] = _nothing
  table_axes: Mapping[str, int] = dataclasses.field(default_factory=dict)
  section: str = None
  records_grid_section: bool = False
  cones: Union[str, Callable[[Any], str]] = ""

  @property
  def section_path(self):
    """The dotted config path of its settings ('model.hash'; '' = the top level)."""
    return f"model.{self.name}" if self.section is None else self.section

  @property
  def shared_section(self):
    """Whether its section holds other settings too (then only the declared ones are read)."""
    return self.section is not None

  def cone_kind(self, settings):
    """'' (points), 'gaussians', 'multisamples' or 'scales': what `settings`' encoding reads."""
    return self.cones(settings) if callable(self.cones) else self.cones

  def natural_network(self, settings):
    """The name of the network that reads it by default."""
    return self.network(settings) if callable(self.network) else self.network


@dataclasses.dataclass(frozen=True)
class Network:
  """A network that reads an encoding's features (networks/).

  name: its config name (config.model.network). settings: the frozen dataclass of its own
    settings (None: it has none beyond protocol.NetworkSettings), from config.<section>
    (shared: only the fields it declares). build: (encoding, settings, protocol.NetworkSettings)
    -> the Flax module (protocol.Network); it raises ValueError naming the config field for
    settings that cannot work together.
  """
  name: str
  build: Callable[[Any, Any, Any], Any]
  settings: type = None
  section: str = "model"

  @property
  def section_path(self):
    """The dotted config path of its settings."""
    return self.section

  @property
  def shared_section(self):
    return True  # config.model: the networks' settings beside the model's others


ENCODINGS = components.Registry("encoding", "config.model.encoding", "ENCODING", {
    "posenc": "nerf_jax.fields.encodings.posenc",
    "ipe": "nerf_jax.fields.encodings.integrated",
    "grid": "nerf_jax.fields.encodings.grid",
    "hash": "nerf_jax.fields.encodings.hashgrid",
    "tensorf": "nerf_jax.fields.encodings.tensorf",
})
DIRECTION_ENCODINGS = components.Registry(
    "direction encoding", "config.dir_encoding", "DIRECTION_ENCODING", {
        "frequency": "nerf_jax.fields.encodings.posenc",
        "sh": "nerf_jax.fields.encodings.spherical_harmonics",
    })
NETWORKS = components.Registry("network", "config.model.network", "NETWORK", {
    "mlp": "nerf_jax.fields.networks.mlp",
    "lattice": "nerf_jax.fields.networks.lattice",
    "density_grid": "nerf_jax.fields.networks.density_grid",
})


def lattice_tables(params, table_axes):
  """[(table, spatial axes)] of every parameter in `params` (a nested dict) whose name starts
  with a prefix of `table_axes` (prefix -> spatial axes)."""
  found = []
  for name, value in params.items():
    if isinstance(value, dict):
      found += lattice_tables(value, table_axes)
      continue
    for prefix, axes in table_axes.items():
      if name.startswith(prefix):
        found.append((value, axes))
  return found
