"""Components found by name, and settings declared once: the one registry shape that fields'
encodings, samplers and loss terms share (big_vision's "the module path is the registry").

A component is a module that defines one record under an agreed attribute name (`ENCODING`,
`SAMPLER`, `LOSS`...). A `Registry` maps short names to module paths (the built-ins, and any
added with `register`); a dotted module path that is not registered works as well. A component's
settings are a frozen dataclass whose fields carry their defaults; `section` turns it into a
config section's defaults, `settings_from` builds it from a section (a misspelt field is a
ValueError naming it) and `signature` turns it into checkpoint-signature entries, so each
setting is written once, in the dataclass. Validation goes in the dataclass's __post_init__.
"""

import dataclasses
import importlib
from typing import Mapping


class Registry:
  """Components of one kind by name.

  kind: what they are, for messages ('encoding'). field: the config field that names one
  ('config.model.encoding'). attribute: the module attribute holding a component's record
  ('ENCODING'). builtins: name -> dotted module path of the built-in components.
  """

  def __init__(self, kind, field, attribute, builtins: Mapping[str, str]):
    self.kind, self.field, self.attribute = kind, field, attribute
    self._modules = dict(builtins)

  def register(self, name, module):
    """Make `name` find the component in `module` (a dotted module path)."""
    self._modules[name] = module

  def unregister(self, name):
    """Forget a name added with `register` (tests)."""
    self._modules.pop(name, None)

  def names(self):
    """The registered names, built-in first."""
    return tuple(self._modules)

  def module_path(self, name):
    """The dotted module path of `name`; ValueError naming the config field if none."""
    path = self._modules.get(name) or (name if "." in name else None)
    if path is None:
      raise ValueError(f"{self.field} must be one of {', '.join(self.names())} or a module "
                       f"path, got {name!r}")
    return path

  def lookup(self, name):
    """The record of `name`: the `attribute` of its module, imported on first use."""
    path = self.module_path(name)
    try:
      module = importlib.import_module(path)
    except ImportError as e:
      raise ValueError(f"{self.field}={name!r}: cannot import {path} ({e})") from None
    record = getattr(module, self.attribute, None)
    if record is None:
      raise ValueError(f"{self.field}={name!r}: {path} defines no {self.attribute} "
                       "(docs/extending.md)")
    return record


def section(settings_class):
  """{field: default} of a settings dataclass: a config section's defaults (lists for tuples,
  as ConfigDict keeps them)."""
  return {f.name: _default(f) for f in dataclasses.fields(settings_class)}


def _default(field):
  if field.default is not dataclasses.MISSING:
    return field.default
  if field.default_factory is not dataclasses.MISSING:  # pytype: disable=invalid-annotation
    return field.default_factory()
  raise TypeError(f"setting {field.name!r} has no default: every setting needs one")


def settings_from(settings_class, values, path, strict=True):
  """settings_class(**values), values being a config section (mapping) at dotted `path`
  ('model.hash'). strict: every key must be a setting (a misspelt one is a ValueError naming
  it); not strict: keys that are not settings are ignored (a shared section). Lists become
  tuples (the dataclass stays hashable)."""
  declared = {f.name for f in dataclasses.fields(settings_class)}
  unknown = sorted(set(values) - declared)
  if unknown and strict:
    raise ValueError(f"config.{path} has no setting {unknown[0]!r} (settings: "
                     f"{', '.join(sorted(declared))})")
  kept = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items() if k in declared}
  return settings_class(**kept)


def signature(settings, prefix, exclude=()):
  """{prefix + field: value} of a settings instance, for a checkpoint signature (tuples as
  lists, as JSON keeps them); `exclude`: fields that change no parameter's shape or meaning."""
  values = dataclasses.asdict(settings)
  return {prefix + k: list(v) if isinstance(v, tuple) else v for k, v in values.items()
          if k not in exclude}
