"""Every setting is declared once, in a settings dataclass, and the config is built from them
(run/schema.py SECTIONS, config_lib.SECTIONS): a field and its dataclass cannot disagree,
and a key that no dataclass declares is refused with one line naming it."""

import dataclasses

import ml_collections
import pytest

from nerf_jax.backend import components as backend_components
from nerf_jax.fields.networks import mlp
from nerf_jax.run import builders, config_lib


def _leaves(section, path=""):
  """{dotted path: value} of every setting (non-section value) of a ConfigDict."""
  found = {}
  for key, value in section.items():
    name = f"{path}.{key}" if path else key
    if isinstance(value, ml_collections.ConfigDict):
      found.update(_leaves(value, name))
    else:
      found[name] = value
  return found


def _declared():
  """{dotted path: (dataclass, field)} of every setting the sections' dataclasses declare."""
  found = {}
  for path, classes in config_lib.SECTIONS.items():
    for cls in classes:
      for field in backend_components.settings_fields(cls):
        name = f"{path}.{field.name}" if path else field.name
        assert name not in found, f"{name} is declared by {found[name][0]} and {cls}"
        found[name] = (cls, field)
  return found


def _default_of(field):
  if field.default is not dataclasses.MISSING:
    return field.default
  return field.default_factory()


def test_every_config_field_is_one_dataclass_field_with_the_same_default():
  config, declared = config_lib.default(), _declared()
  leaves = _leaves(config)
  assert set(leaves) == set(declared)  # nothing hand-written, nothing left out
  for name, value in leaves.items():
    cls, field = declared[name]
    assert value == _default_of(field), f"config.{name}={value!r}, {cls.__name__} says otherwise"
  assert len(leaves) > 150  # the whole config, not a corner of it


def test_the_settings_built_from_the_default_config_are_the_dataclasses_defaults():
  config = config_lib.default()
  # The MLP's width is the shared model.width (it used to arrive as `hidden`): one name.
  shared = builders.network_settings(config)
  assert shared.width == config.model.width == 64 and shared.view_width == 32
  assert config_lib.SECTIONS["model"].count(mlp.Settings) == 1
  assert "width" not in {f.name for f in dataclasses.fields(mlp.Settings)}
  batch = builders.batch_settings(config)
  assert (batch.batch_rays, batch.images_per_step) == (512, 5)
  opt = builders.optimizer_settings(config)
  assert opt.warmup_steps == 50 and opt.lr == 5e-3
  assert builders.image_settings(config).chunk == 4096


@pytest.mark.parametrize("field, message", [
    ("model.widht", "config.model has no setting 'widht'"),
    ("num_sample", "config has no setting 'num_sample'"),
    ("train.batch_ray", "config.train has no setting 'batch_ray'"),
    ("data.scene_bounds", "config.data has no setting 'scene_bounds'"),
    ("model.grid.resolution", "config.model.grid has no setting 'resolution'"),
    ("loss.colour.wieght", "config.loss.colour has no setting 'wieght'"),
])
def test_a_misspelt_setting_is_one_line_naming_it(field, message):
  config = config_lib.default()
  *path, name = field.split(".")
  node = config
  for part in path:
    node = node[part]
  node[name] = 1  # a config file can add any key: the check must catch it
  with pytest.raises(ValueError, match=message):
    builders.check_config(config)
  with pytest.raises(ValueError, match=message):
    builders.make_field(config)


def test_a_section_nested_in_a_shared_one_is_anothers_and_passes():
  config = config_lib.default()
  config.model.fourier = ml_collections.ConfigDict({"features": 8})  # an encoding's own
  builders.check_config(config)  # read strictly by that encoding when it is used


def test_two_dataclasses_cannot_declare_one_setting():
  @dataclasses.dataclass(frozen=True)
  class A:
    width: int = 1

  @dataclasses.dataclass(frozen=True)
  class B:
    width: int = 2

  with pytest.raises(TypeError, match="'width' is declared by both"):
    backend_components.section(A, B)


def _registries():
  from nerf_jax.fields import registry  # pylint: disable=import-outside-toplevel
  from nerf_jax.samplers import registry as samplers  # pylint: disable=import-outside-toplevel
  from nerf_jax.train import losses  # pylint: disable=import-outside-toplevel
  return (registry.ENCODINGS, registry.DIRECTION_ENCODINGS, registry.NETWORKS,
          samplers.REGISTRY, losses.REGISTRY)


def test_every_built_in_is_one_record_named_as_its_module():
  for reg in _registries():
    for name in reg.names():
      record = reg.lookup(name)
      assert isinstance(record, backend_components.Component), (reg.kind, name)
      # One name: the registered one, the record's and the module's are the same.
      assert record.name == name == reg.module_path(name).rsplit(".", 1)[-1], (reg.kind, name)
      if record.settings is not None:
        assert dataclasses.is_dataclass(record.settings)
        assert isinstance(record.entries(record.settings()), dict)  # a signature for any


def test_a_saved_run_with_a_retired_setting_still_restores_its_config(tmp_path, capsys):
  saved = config_lib.default().to_dict()
  saved["train"]["retired_knob"] = 3  # a field an older version had
  saved["model"]["fourier"] = {"features": 8}  # a component's own section is kept
  (tmp_path / "config.json").write_text(ml_collections.ConfigDict(saved).to_json())
  config = config_lib.load_saved(str(tmp_path))
  assert "retired_knob" not in config.train and config.model.fourier.features == 8
  assert "config.train.retired_knob is no longer a setting; ignored" in capsys.readouterr().out
  builders.check_config(config)  # what restoring builds from passes
