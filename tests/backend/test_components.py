"""The one registry shape and settings declared once (nerf_jax/backend/components.py)."""

import dataclasses
import sys
import types
from typing import Sequence

import pytest

from nerf_jax.backend import components


@dataclasses.dataclass(frozen=True)
class Settings:
  """A component's settings, as every component declares them."""
  levels: int = 4  # resolution levels
  sizes: Sequence[int] = (8, 16)  # lattice points per side
  dtype: str = "float32"  # gather dtype (no parameter's shape depends on it)

  def __post_init__(self):
    if self.levels < 1:
      raise ValueError(f"config.model.thing.levels={self.levels}: use 1 or more")


@pytest.fixture
def registry(monkeypatch):
  """A registry of one built-in ('thing', a module made here) and the name of that module."""
  module = types.ModuleType("thing_module_for_test")
  module.RECORD = components.Component("thing", Settings, lambda settings, context: settings)
  monkeypatch.setitem(sys.modules, module.__name__, module)
  return components.Registry("thing", "config.model.thing", "RECORD", "model",
                             {"thing": module.__name__})


def test_lookup_by_name_and_by_module_path(registry):
  assert registry.lookup("thing").settings is Settings
  registry.register("alias", "thing_module_for_test")
  assert registry.names() == ("thing", "alias")  # built-in first
  assert registry.lookup("alias") is registry.lookup("thing")
  registry.unregister("alias")
  assert registry.names() == ("thing",)


def test_a_dotted_path_needs_no_registration(registry, monkeypatch):
  module = types.ModuleType("pkg_for_test.other")
  module.RECORD = components.Component("other", None, lambda settings, context: None)
  monkeypatch.setitem(sys.modules, "pkg_for_test", types.ModuleType("pkg_for_test"))
  monkeypatch.setitem(sys.modules, "pkg_for_test.other", module)
  assert registry.lookup("pkg_for_test.other") is module.RECORD


def test_errors_name_the_config_field(registry):
  with pytest.raises(ValueError, match=r"config.model.thing must be one of thing or a module "
                                       r"path, got 'nope'"):
    registry.lookup("nope")
  with pytest.raises(ValueError, match=r"config.model.thing='no_pkg.no_mod': cannot import"):
    registry.lookup("no_pkg.no_mod")
  with pytest.raises(ValueError, match=r"defines no RECORD"):
    registry.lookup("json.decoder")  # a module, but no record in it


def test_section_gives_the_defaults_of_every_setting():
  assert components.section(Settings) == {"levels": 4, "sizes": (8, 16), "dtype": "float32"}

  @dataclasses.dataclass(frozen=True)
  class NoDefault:
    size: int

  with pytest.raises(TypeError, match="'size' has no default"):
    components.section(NoDefault)


def test_settings_from_a_section():
  settings = components.settings_from(Settings, {"levels": 2, "sizes": [4, 8]}, "model.thing")
  assert settings == Settings(levels=2, sizes=(4, 8), dtype="float32")  # lists become tuples
  hash(settings)  # hashable: a static argument of jitted functions
  with pytest.raises(ValueError, match="config.model.thing has no setting 'levles'"):
    components.settings_from(Settings, {"levles": 2}, "model.thing")
  shared = {"levels": 3, "width": 64}  # a shared section: other fields are not ours
  assert components.settings_from(Settings, shared, "model", strict=False).levels == 3
  with pytest.raises(ValueError, match="config.model.thing.levels=0"):  # __post_init__
    components.settings_from(Settings, {"levels": 0}, "model.thing")


def test_signature_entries():
  entries = components.signature(Settings(levels=2), "thing_", exclude=("dtype",))
  assert entries == {"thing_levels": 2, "thing_sizes": [8, 16]}  # JSON's lists
