"""run/builders.py's builders, each against what the config says, by hand: the encoding and its
settings (encoding_family), the shared network settings (network_settings), the field's parts
(make_field: every built-in encoding under every network that can read it, the parameter names
checkpoints store), the sampler (make_sampler) and the ray renderer (make_ray_renderer), and the
one-line ValueError naming the config field that each gives for a setting that cannot work."""

import dataclasses

import jax
import pytest

from nerf_jax.backend import components as backend_components
from nerf_jax.fields import registry
from nerf_jax.fields.encodings import grid, posenc, sh, tensorf
from nerf_jax.fields.encodings import hash as hashgrid
from nerf_jax.fields.networks import density_grid, lattice, mlp
from nerf_jax.run import builders
from nerf_jax.samplers import placement as sampler_lib
from tests.helpers import small_config

# Small sections for each built-in encoding, so the parameters' shapes stay tiny.
SMALL = {"posenc": {},
         "grid": {"model.grid.resolutions": (4, 8), "model.grid.features": 2},
         "hash": {"model.hash.levels": 3, "model.hash.log2_size": 8, "model.hash.features": 2,
                  "model.hash.base_resolution": 4, "model.hash.max_resolution": 16},
         "tensorf": {"model.tensorf.resolutions": (4, 8), "model.tensorf.rank": 2}}
ENCODINGS = {"posenc": posenc.Frequency, "grid": grid.DenseGrid, "hash": hashgrid.HashGrid,
             "tensorf": tensorf.TensoRF}


def _config(encoding="posenc", **fields):
  return small_config({"model.encoding": encoding, **SMALL[encoding]}, **fields)


def _param_shapes(field):
  """{name: shape} of the field's parameters (jax.eval_shape: nothing computed)."""
  tree = jax.eval_shape(field.init, jax.random.PRNGKey(0))
  return {"/".join(str(k.key) for k in path): leaf.shape
          for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]}


def test_every_built_in_encoding_has_a_section_built_from_its_settings():
  config = small_config()
  assert set(registry.ENCODINGS.names()) >= set(ENCODINGS)
  for name in ENCODINGS:
    config.model.encoding = name
    record, settings = builders.encoding_family(config)
    assert record.name == name and isinstance(settings, record.settings)
    section = config
    for part in filter(None, registry.ENCODINGS.section_path(record).split(".")):
      section = section[part]
    for field in dataclasses.fields(settings):  # each setting is its section's value
      value = section[field.name]
      assert getattr(settings, field.name) == (tuple(value) if isinstance(value, list)
                                               else value)
    # The config's defaults are the dataclass's own (configs/default.py: builders.section).
    defaults = small_config(base="default")
    for part in filter(None, registry.ENCODINGS.section_path(record).split(".")):
      defaults = defaults[part]
    assert {f: defaults[f] for f in backend_components.section(record.settings)} == (
        backend_components.section(record.settings))


def test_a_wrong_encoding_section_is_a_one_line_error_naming_the_field():
  config = _config("hash")
  config.model.hash.level = 4  # misspelt
  with pytest.raises(ValueError, match="config.model.hash has no setting 'level'"):
    builders.encoding_family(config)
  config = _config("hash", **{"model.hash.log2_size": 30})  # validated in __post_init__
  with pytest.raises(ValueError, match="model.hash.log2_size must be in"):
    builders.encoding_family(config)
  config = _config("grid", **{"model.grid.colour_hash_resolution": 64})
  with pytest.raises(ValueError, match="need config.model.grid.density_resolutions"):
    builders.make_field(config)
  config = _config()
  config.model.encoding = "no_such"
  with pytest.raises(ValueError, match="config.model.encoding must be one of"):
    builders.encoding_family(config)
  config.model.encoding = "tensorf"
  del config.model["tensorf"]
  with pytest.raises(ValueError, match="config.model.tensorf is missing"):
    builders.encoding_family(config)


def test_network_settings_are_config_models_shared_fields():
  config = _config("grid", **{"model.grid_box": (-1.0, -2.0, -3.0, 1.0, 2.0, 3.0),
                              "model.view_dependent": True, "model.appearance_dims": 4})
  shared = builders.network_settings(config, num_images=7)
  m = config.model
  assert (shared.width, shared.view_width, shared.view_depth) == (m.width, m.view_width,
                                                                    m.view_depth)
  assert shared.view_dependent and shared.appearance_dims == 4
  assert shared.appearance_images == 7
  assert builders.network_settings(config, 0).appearance_images == 1
  assert shared.grid_box == (-1.0, -2.0, -3.0, 1.0, 2.0, 3.0)
  assert shared.grid_bound == m.grid_bound
  # An unbounded scene: the lattices cover all of contracted space, twice the inner box.
  config = _config("grid", **{"data.contraction": "linf", "data.scene_bound": 2.5})
  assert builders.network_settings(config).grid_bound == 5.0


@pytest.mark.parametrize("name", sorted(ENCODINGS))
def test_each_encoding_gets_its_own_network_and_its_parameter_names(name):
  field = builders.make_field(_config(name))
  own = {"posenc": mlp.NerfMLP}.get(name, lattice.LatticeHead)
  assert type(field.network) is own and type(field.network.encoding) is ENCODINGS[name]
  assert builders.network_name(_config(name)) == ("mlp" if name == "posenc" else "lattice")
  shapes = _param_shapes(field)
  tables = {"posenc": set(), "grid": {"grid_4", "grid_8"}, "hash": {"hash_table"},
            "tensorf": {f"{kind}_{r}_{m}" for kind in ("plane", "line") for r in (4, 8)
                        for m in range(3)}}[name]
  assert tables <= set(shapes)  # the tables sit directly in the network's parameters
  if name == "hash":
    settings = field.network.encoding.settings
    rows = sum(hashgrid.level_rows(settings.resolutions, settings.log2_size))
    assert shapes["hash_table"] == (rows, 2)
  if name == "posenc":  # 3 + 2·3·bands inputs: the frequency bands of debug.py's 4
    assert shapes["layer_0/kernel"] == (posenc.encoded_width(3, 4), 32)


@pytest.mark.parametrize("name", sorted(ENCODINGS))
def test_any_encoding_can_be_read_by_either_network(name):
  for network, cls in (("mlp", mlp.NerfMLP), ("lattice", lattice.LatticeHead)):
    config = _config(name, **{"model.network": network})
    field = builders.make_field(config)
    assert type(field.network) is cls and type(field.network.encoding) is ENCODINGS[name]
    width = field.network.encoding.width(3)
    first = "layer_0/kernel" if network == "mlp" else "hidden/kernel"
    assert _param_shapes(field)[first][0] == width  # it reads the encoding's features


def test_the_grid_encoding_with_density_levels_takes_the_split_network():
  config = _config("grid", **{"model.grid.density_resolutions": (8,),
                              "model.density_activation": "softplus"})
  field = builders.make_field(config)
  assert type(field.network) is density_grid.DensityGridNeRF and field.splits_density
  assert {"density_8", "grid_4", "grid_8"} <= set(_param_shapes(field))
  config.model.density_activation = "relu"
  with pytest.raises(ValueError, match="config.model.density_activation 'softplus' or 'exp'"):
    builders.make_field(config)
  config = _config("hash", **{"model.network": "density_grid"})
  with pytest.raises(ValueError, match="config.model.network='density_grid'"):
    builders.make_field(config)


def test_direction_encodings_and_the_fields_one_line_errors():
  field = builders.make_field(_config(**{"model.view_dependent": True}))
  assert field.directions == posenc.Frequency(2) and field.dir_width == posenc.encoded_width(3, 2)
  config = _config(**{"dir_encoding": "sh", "dir_encode_dims": 3})
  field = builders.make_field(config)
  assert field.directions == sh.SphericalHarmonics(3) and field.dir_width == 9
  for fields, message in (({"dir_encoding": "sh", "dir_encode_dims": 0}, "dir_encode_dims"),
                          ({"dir_encoding": "polar"}, "config.dir_encoding must be one of"),
                          ({"model.network": "nope"}, "config.model.network must be one of"),
                          ({"model.appearance_dims": -1}, "config.model.appearance_dims=-1"),
                          ({"model.matmul_precision": "fastest"}, "matmul_precision"),
                          ({"pos_encode_dims": -1}, "config.pos_encode_dims=-1")):
    with pytest.raises(ValueError, match=message):
      builders.make_field(_config(**fields))


def test_the_field_takes_the_configs_activation_contraction_and_codes():
  config = _config("grid", **{"model.density_activation": "exp", "model.density_noise": 0.5,
                              "data.contraction": "l2", "data.scene_bound": 2.0,
                              "model.appearance_dims": 3})
  field = builders.make_field(config, num_images=5)
  assert (field.density_activation, field.density_noise) == ("exp", 0.5)
  assert (field.contraction, field.inner_radius) == ("l2", 2.0) and field.uses_images
  assert _param_shapes(field)["appearance"] == (5, 3)


def test_make_sampler_and_its_one_line_errors():
  config = _config(**{"data.scene_bound": 1.5, "num_samples": 12})
  sampler = builders.make_sampler(config)
  assert type(sampler) is sampler_lib.Sampler and sampler.num_samples == 12
  assert sampler.occupancy is None
  config.occupancy.enabled = True
  assert builders.make_sampler(config).occupancy.resolution == config.occupancy.resolution
  for fields, message in (
      ({"occupancy.enabled": True, "data.scene_bound": 0.0},
       "config.occupancy.enabled needs config.data.scene_bound"),
      ({"occupancy.enabled": True, "data.scene_bound": 1.5, "num_fine_samples": 8},
       "config.occupancy.enabled and config.num_fine_samples"),
      ({"data.contraction": "linf", "data.scene_bound": 0.0},
       "config.data.contraction needs config.data.scene_bound"),
      ({"sampler": "proposal", "num_fine_samples": 8}, "config.sampler='proposal'")):
    with pytest.raises(ValueError, match=message):
      builders.make_sampler(_config(**fields))


def test_make_ray_renderer_and_its_one_line_errors():
  renderer = builders.make_ray_renderer(_config(num_fine_samples=8))
  assert renderer.num_fine_samples == 8 and renderer.networks == ("coarse", "fine")
  shared = builders.make_ray_renderer(_config(num_fine_samples=8,
                                                **{"model.shared_fine": True}))
  assert shared.networks == ("coarse",)
  with pytest.raises(ValueError, match="config.train.sample_budget needs config.occupancy"):
    builders.make_ray_renderer(_config(**{"train.sample_budget": 1000}))
