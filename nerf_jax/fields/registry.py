"""The encoding families, found by name.

An encoding family is one module that holds its network (a Flax module following
network.Network), the frozen dataclass of its settings, and an `ENCODING = Encoding(...)` record
saying how to build it and what its checkpoints record. `config.model.encoding` names it: a
registered name ('posenc', 'grid', 'hash', 'tensorf', or one added with `register`), or the
dotted path of any importable module that defines ENCODING (as big_vision names its models).
Its settings are its own config section, `config.model.<name>` (run/experiment.py builds them
with `settings_from`), so adding an encoding is one module plus its config section
(docs/extending.md, tests/topics/test_extending.py).
"""

import dataclasses
import importlib
from typing import Any, Callable, Mapping

from nerf_jax.fields import network

# Built-in families: name -> module.
_MODULES = {
    "posenc": "nerf_jax.fields.networks.mlp",
    "grid": "nerf_jax.fields.networks.grid",
    "hash": "nerf_jax.fields.networks.hash",
    "tensorf": "nerf_jax.fields.networks.tensorf",
}


def _nothing(settings):
  del settings
  return {}


@dataclasses.dataclass(frozen=True)
class Encoding:
  """An encoding family.

  name: its config name; its settings are config.model.<name> (`section`).
  settings: the frozen dataclass of its settings (its section's fields, each with a default).
  build: (settings, network.NetworkSettings) -> the network (network.Network). It raises
    ValueError naming the config field for settings that cannot work together.
  signature: settings -> {key: JSON value}, the entries of the checkpoint signature (the
    settings that fix its parameters' shapes and meaning); a checkpoint restores only under
    equal entries, so keep a family's keys once released.
  raw_positions: the network takes world positions (its lookup is the encoding); False: their
    positional encoding with config.pos_encode_dims bands (the MLP).
  table_axes: parameter-name prefixes of its lattice tables -> their spatial axes (the last axis
    holds features): the tables train.tv_weight's total variation applies to.
  section: the dotted config path of its settings; None = model.<name>. A family whose section
    is shared ('model') takes the fields its settings declare from it.
  records_grid_section: its checkpoints also record config.model.grid's fields (the hash and
    TensoRF families' have since they were added, so theirs keep restoring).
  """
  name: str
  settings: type
  build: Callable[[Any, Any], Any]
  signature: Callable[[Any], dict] = _nothing
  raw_positions: bool = True
  table_axes: Mapping[str, int] = dataclasses.field(default_factory=dict)
  section: str = None
  records_grid_section: bool = False

  @property
  def section_path(self):
    """The dotted config path of the family's settings ('model.hash')."""
    return self.section or f"model.{self.name}"


def register(name, module):
  """Make `name` find the family in `module` (a dotted module path defining ENCODING)."""
  _MODULES[name] = module


def names():
  """The registered names, built-in first."""
  return tuple(_MODULES)


def lookup(name):
  """The Encoding of `name` (registered, or a dotted module path). ValueError naming
  config.model.encoding when there is none."""
  path = _MODULES.get(name) or (name if "." in name else None)
  known = ", ".join(names())
  if path is None:
    raise ValueError(f"config.model.encoding must be one of {known} or a module path, got "
                     f"{name!r}")
  try:
    module = importlib.import_module(path)
  except ImportError as e:
    raise ValueError(f"config.model.encoding={name!r}: cannot import {path} ({e})") from None
  family = getattr(module, "ENCODING", None)
  if not isinstance(family, Encoding):
    raise ValueError(f"config.model.encoding={name!r}: {path} defines no ENCODING = "
                     "registry.Encoding(...) (docs/extending.md)")
  return family


def settings_from(family, section):
  """The family's settings dataclass from `section` (a mapping of its config section). Every
  field of an own section must be a setting (a misspelt one is an error naming it); a shared
  section ('model') gives only the fields the settings declare."""
  declared = {f.name for f in dataclasses.fields(family.settings)}
  unknown = sorted(set(section) - declared)
  if unknown and family.section is None:
    raise ValueError(f"config.{family.section_path} has no setting {unknown[0]!r} (settings: "
                     f"{', '.join(sorted(declared))})")
  values = {k: tuple(v) if isinstance(v, list) else v for k, v in section.items()
            if k in declared}
  return family.settings(**values)


def build(family, settings, shared):
  """family.build(settings, shared), checked to follow network.Network."""
  net = family.build(settings, shared)
  if not isinstance(net, network.Network):
    raise TypeError(f"encoding {family.name!r}: its network {type(net).__name__} lacks "
                    "num_levels or splits_density (fields/network.py)")
  return net


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
