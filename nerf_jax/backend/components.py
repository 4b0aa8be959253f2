"""Components found by name, and settings declared once: the one record and the one registry
that fields' encodings and networks, samplers and loss terms share (big_vision's "the module
path is the registry").

A component is a module that defines one record, a `Component` (or a kind's subclass of it that
adds what only that kind needs), under its kind's attribute name (`ENCODING`, `NETWORK`,
`SAMPLER`, `LOSS`). A `Registry` maps short names to module paths (the built-ins, and any added
with `register`); a dotted module path that is not registered works as well. One rule places a
component's settings: config.<registry root>.<name> (`Registry.section_path`), read strictly,
unless its record names an older shared section (config.model for the MLP, the top level for
the positions' bands), whose every key the entry layer checks against the dataclasses that
share it (`check_section`). A component's settings are a frozen dataclass whose fields carry
their defaults; `section` turns it into a config section's defaults, `settings_from` builds it
from a section (a misspelt field is a ValueError naming it) and `signature` turns it into
checkpoint-signature entries, so each setting is written once, in the dataclass. Validation goes
in the dataclass's __post_init__.
"""

import dataclasses
import importlib
from typing import Any, Callable, Mapping


@dataclasses.dataclass(frozen=True)
class Component:
  """The record of a component (one per module, under its kind's attribute name).

  name: its registered name, also the last part of its config section.
  settings: the frozen dataclass of its settings (each field with its default and a one-line
    comment; validation in __post_init__ raising ValueError naming the config field), or None:
    it has none.
  build: its kind's builder, (settings, context) -> the part (the kind says what context is).
  signature: settings -> {key: JSON value}: its entries of the checkpoint signature (the
    settings that fix its parameters' shapes and meaning); a resume under other values names
    the key that changed. None: every setting, keyed '<name>_<setting>' (`entries`).
  section: the dotted config path of its settings; None = the rule, <registry root>.<name>. A
    section named here is shared (it holds other settings too): it is read leniently and
    checked whole against every dataclass sharing it (run/builders.check_config).
  """
  name: str
  settings: Any
  build: Callable
  signature: Callable[[Any], dict] = None
  section: str = None

  def entries(self, settings):
    """{key: JSON value}: its entries of the checkpoint signature for `settings`."""
    if self.signature is not None:
      return self.signature(settings)
    return {} if settings is None else signature(settings, f"{self.name}_")

  def section_in(self, root):
    """The dotted config path of its settings under a registry's `root` ('' = top level)."""
    if self.section is not None:
      return self.section
    return f"{root}.{self.name}" if root else self.name

  @property
  def strict(self):
    """Whether its section is its own, so that every key must be one of its settings."""
    return self.section is None


class Registry:
  """Components of one kind by name.

  kind: what they are, for messages ('encoding'). field: the config field that names one
  ('config.model.encoding'). attribute: the module attribute holding a component's record
  ('ENCODING'). root: the config section under which each component's own section
  <root>.<name> lives ('model', 'loss'; '' = the top level). builtins: name -> dotted module
  path of the built-in components.
  """

  def __init__(self, kind, field, attribute, root, builtins: Mapping[str, str]):
    self.kind, self.field, self.attribute, self.root = kind, field, attribute, root
    self._modules = dict(builtins)
    self._builtins = dict(builtins)

  def register(self, name, module):
    """Make `name` find the component in `module` (a dotted module path)."""
    self._modules[name] = module

  def unregister(self, name):
    """Forget a name added with `register` (tests)."""
    self._modules.pop(name, None)

  def names(self):
    """The registered names, built-in first."""
    return tuple(self._modules)

  def added(self):
    """{name: module path} of the names added with `register` (what a run records so that
    restoring it finds them again, run/config_lib.save)."""
    return {name: path for name, path in self._modules.items()
            if self._builtins.get(name) != path}

  def section_path(self, record):
    """The dotted config path of `record`'s settings (Component.section_in this root)."""
    return record.section_in(self.root)

  def settings(self, record, values):
    """`record`'s settings dataclass built from `values`, its section (a dict, or None where
    the config lacks it; strict for a section of its own); None if it has none. ValueError
    naming the field if the section is missing or a setting is wrong."""
    if record.settings is None:
      return None
    path = self.section_path(record)
    if values is None:
      raise ValueError(f"config.{path} is missing: the settings of {self.kind} "
                       f"{record.name!r}")
    if not record.strict:  # a shared section: its nested sections are other components'
      values = {k: v for k, v in values.items() if not isinstance(v, dict)}
    return settings_from(record.settings, values, path, strict=record.strict)

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
    if not isinstance(record, Component):
      raise ValueError(f"{self.field}={name!r}: {path} defines no {self.attribute} "
                       "(a components.Component record: docs/extending.md)")
    return record


def derived(default=dataclasses.MISSING):
  """A dataclass field the builder fills in from elsewhere (another section, the data), not a
  config setting: `section` leaves it out and `settings_from` refuses it in a section."""
  return dataclasses.field(default=default, metadata={"derived": True})


def settings_fields(settings_class):
  """The dataclass fields of `settings_class` that are config settings (not `derived`)."""
  return [f for f in dataclasses.fields(settings_class) if not f.metadata.get("derived")]


def section(*settings_classes):
  """{field: default} of one or more settings dataclasses: a config section's defaults, in
  declaration order. TypeError if two declare the same setting (each is declared once)."""
  values, owner = {}, {}
  for cls in settings_classes:
    for f in settings_fields(cls):
      if f.name in owner:
        raise TypeError(f"setting {f.name!r} is declared by both {owner[f.name].__qualname__} "
                        f"and {cls.__qualname__}: declare it once")
      owner[f.name], values[f.name] = cls, _default(f)
  return values


def _default(field):
  if field.default is not dataclasses.MISSING:
    return field.default
  if field.default_factory is not dataclasses.MISSING:  # pytype: disable=invalid-annotation
    return field.default_factory()
  raise TypeError(f"setting {field.name!r} has no default: every setting needs one")


def settings_from(settings_class, values, path, strict=True, **derived_values):
  """settings_class(**values, **derived_values), values being a config section (mapping) at
  dotted `path` ('model.hash') and derived_values the `derived` fields. strict: every key of
  `values` must be a setting (a misspelt one is a ValueError naming it); not strict: keys that
  are not its settings are ignored (a section shared with other dataclasses, checked whole by
  `check_section`). Lists become tuples (the dataclass stays hashable)."""
  declared = {f.name for f in settings_fields(settings_class)}
  unknown = sorted(set(values) - declared)
  if unknown and strict:
    raise ValueError(unknown_setting(path, unknown[0], declared))
  kept = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items() if k in declared}
  return settings_class(**kept, **derived_values)


def unknown_setting(path, name, declared):
  """The one line for a key `name` of config.<path> that is not among `declared`."""
  where = f"config.{path}" if path else "config"
  return f"{where} has no setting {name!r} (settings: {', '.join(sorted(declared))})"


def check_section(values, path, settings_classes, subsections=()):
  """ValueError naming the first key of `values` (a config section at dotted `path`, '' = the
  top level) that none of `settings_classes` declares and that is not one of `subsections`
  (the names of the sections nested in it)."""
  declared = {f.name for cls in settings_classes for f in settings_fields(cls)}
  declared |= set(subsections)
  for name in values:
    if name not in declared:
      raise ValueError(unknown_setting(path, name, declared))


def signature(settings, prefix, exclude=()):
  """{prefix + field: value} of a settings instance, for a checkpoint signature (tuples as
  lists, as JSON keeps them); `exclude`: fields that change no parameter's shape or meaning."""
  names = [f.name for f in settings_fields(type(settings))]
  values = {name: getattr(settings, name) for name in names}
  return {prefix + k: list(v) if isinstance(v, tuple) else v for k, v in values.items()
          if k not in exclude}
