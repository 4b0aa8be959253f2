"""The encodings and networks of a field, found by name (backend/components.Registry).

An encoding is one module of its own (encodings/<name>.py): its pure math, the frozen dataclass
of its settings, and an `ENCODING = registry.Encoding(...)` record saying how to build it, which
network reads it unless config.model.network names one, and what its checkpoints record.
`config.model.encoding` names a position encoding ('posenc', 'ipe', 'grid', 'hash', 'tensorf', one
added with `ENCODINGS.register`, or the dotted path of any module defining ENCODING: big_vision's
"the module path is the registry"); `config.dir_encoding` a direction encoding ('frequency',
'sh': modules defining DIRECTION_ENCODING, the same record). A network is a module of networks/
defining `NETWORK = registry.Network(...)` ('mlp', 'lattice', 'density_grid'). Both records are
components.Component: settings are their own config section, config.model.<name>
(`Registry.settings`), so adding an encoding or a network is one module plus its config
section (docs/extending.md).
"""

import dataclasses
from typing import Any, Callable, Mapping, Union

from nerf_jax.backend import components


@dataclasses.dataclass(frozen=True)
class Encoding(components.Component):
  """A position or direction encoding's record (components.Component, and what only encodings
  have).

  build: (settings, protocol.NetworkSettings) -> the encoding (protocol.Encoding), which the
    network applies (a direction encoding: the Field).
  signature: as Component's; keep a released encoding's keys, so its checkpoints restore (the
    built-in lattices' are prefixed: grid_resolutions, hash_levels...).
  section: as Component's: model.<name>, or '' (the top level: the bands' and directions'
    settings, shared).
  network: the name of the network that reads it when config.model.network is '' ('mlp': NeRF's
    MLP, 'lattice': the grids' tiny head), or settings -> that name.
  table_axes: parameter-name prefixes of its lattice tables -> their spatial axes (the last axis
    holds features): the tables the total variation (loss.total_variation) smooths.
  records_grid_section: its checkpoints also record config.model.grid's lattice entries (the
    hash and TensoRF encodings' have since they were added, so theirs keep restoring).
  cones: what it encodes of each sample's frustum (cameras/cones.py; the rays then carry their
    radii, Rays.radii), or settings -> that: '' points; 'gaussians' mip-NeRF's Gaussian, the
    Field hands `features` the means with their diagonal variances as `var=`; 'multisamples'
    Zip-NeRF's six points, handed as `multisamples=(points, std)` beside the means; 'scales'
    the same with each frustum's mean as its one point (levels weighted, no multisampling).
  """
  network: Union[str, Callable[[Any], str]] = "mlp"
  table_axes: Mapping[str, int] = dataclasses.field(default_factory=dict)
  records_grid_section: bool = False
  cones: Union[str, Callable[[Any], str]] = ""

  def cone_kind(self, settings):
    """'' (points), 'gaussians', 'multisamples' or 'scales': what `settings`' encoding reads."""
    return self.cones(settings) if callable(self.cones) else self.cones

  def natural_network(self, settings):
    """The name of the network that reads it by default."""
    return self.network(settings) if callable(self.network) else self.network


@dataclasses.dataclass(frozen=True)
class Network(components.Component):
  """A network's record (components.Component): one that reads an encoding's features
  (networks/).

  settings: the frozen dataclass of its own settings (None: it has none beyond
    protocol.NetworkSettings), from config.model.<name> (the rule) or a shared section it names.
  build: (encoding, settings, protocol.NetworkSettings) -> the Flax module (protocol.Network);
    it raises ValueError naming the config field for settings that cannot work together.
  signature: as Component's: its entries of the checkpoint signature.
  """


@dataclasses.dataclass(frozen=True)
class Parts:
  """config.model's fields naming the field's parts."""
  encoding: str = "posenc"  # positions: 'posenc' (bands), 'grid' (fast.py), 'hash', 'tensorf'
  network: str = ""  # the network reading them: '' = the encoding's own ('mlp', 'lattice'), a name


ENCODINGS = components.Registry("encoding", "config.model.encoding", "ENCODING", "model", {
    "posenc": "nerf_jax.fields.encodings.posenc",
    "ipe": "nerf_jax.fields.encodings.ipe",
    "grid": "nerf_jax.fields.encodings.grid",
    "hash": "nerf_jax.fields.encodings.hash",
    "tensorf": "nerf_jax.fields.encodings.tensorf",
})
DIRECTION_ENCODINGS = components.Registry(
    "direction encoding", "config.dir_encoding", "DIRECTION_ENCODING", "", {
        "frequency": "nerf_jax.fields.encodings.frequency",
        "sh": "nerf_jax.fields.encodings.sh",
    })
NETWORKS = components.Registry("network", "config.model.network", "NETWORK", "model", {
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
