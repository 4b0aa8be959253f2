"""The config's schema lives in the library (run/schema.py): configs/default.py is its
`defaults()`, and its docstring lists every section with the dataclasses that declare it."""

import re

from nerf_jax.configs import default
from nerf_jax.run import config_lib, schema


def test_the_default_config_file_is_the_schemas_defaults():
  built = schema.defaults().to_dict()
  assert default.get_config().to_dict() == built == config_lib.default().to_dict()
  assert config_lib.SECTIONS == schema.all_sections()
  assert set(schema.SECTIONS) <= set(schema.all_sections())
  assert {"model.grid", "proposal", "loss.colour"} <= set(schema.component_sections())


def _named(cls):
  """'run/settings.RunSettings' of a dataclass of nerf_jax (a package's __init__: its folder)."""
  module = cls.__module__[len("nerf_jax."):].replace(".", "/")
  return f"{module}.{cls.__qualname__}"


def test_the_default_config_files_docstring_lists_every_section_and_its_dataclasses():
  text = " ".join(default.__doc__.split())
  for path, classes in schema.SECTIONS.items():
    if path:
      assert f"config.{path} " in text, path
    for cls in classes:
      assert _named(cls) in text, (path, _named(cls))
  for path in schema.component_sections():
    name = path.rsplit(".", 1)[-1]
    assert re.search(rf"\b{name}\b", text), path  # config.model.grid; loss.<term> (colour, ...)
  assert _named(schema.SECTIONS["data"][0]) == "data/data_settings.DataSettings"


def test_the_config_file_holds_no_schema():
  names = {n for n in vars(default) if not n.startswith("__")}
  assert names == {"schema", "get_config"}  # SECTIONS, COMPONENTS, ...: run/schema.py's
