"""docs/extending.md's walk-through, run as written: its encoding module and its config file are
written verbatim into new files, the config file is loaded by the library's own loader (nothing
injected), trained a few steps through the library's training job, and restored; no file of the
tree is touched."""

import jax
import numpy as np
import pytest

from nerf_jax.fields import registry
from nerf_jax.run import builders, config_lib, experiment, signature, train_lib
from tests import helpers

# The shrinking every quick training test applies (tests/helpers.TINY_GRID's sizes), on top of
# the doc's config file as loaded.
SHRINK = {"data.num_views": 6, "data.image_size": 16, "data.holdout_from": 5, "num_samples": 16,
          "model.depth": 2, "model.width": 16, "model.fourier.features": 8,
          "train.batch_rays": 256, "train.max_steps": 20, "train.log_every": 20,
          "train.checkpoint_every": 20, "render.after_training": False,
          "render.video_frames": 0, "render.chunk": 256, "render.march_grid": 16}


@pytest.fixture
def doc_files(tmp_path, monkeypatch):
  """The doc's module (my_encodings/fourier.py) and config file (my_config.py), written into
  tmp_path, which goes on sys.path as the doc's PYTHONPATH; returns the config file's path."""
  path = helpers.write_walkthrough(tmp_path, "tests/topics/test_extending.py",
                                   "my_encodings/fourier.py")
  monkeypatch.syspath_prepend(str(tmp_path))
  return path


def _loaded(path):
  """The doc's config file through config_lib.load, shrunk to a quick run."""
  config = config_lib.load(path)
  for field, value in SHRINK.items():
    config_lib.set_field(config, field, value)
  return config


def test_the_docs_encoding_is_gamma_of_its_fixed_gaussian_matrix(doc_files):
  from my_encodings import fourier  # pylint: disable=g-import-not-at-top  (written by the fixture)
  encoding = fourier.build(fourier.Settings(features=5, scale=3.0, seed=7), None)
  b = np.asarray(encoding.matrix(), np.float64)
  assert b.shape == (5, 3) and np.array_equal(b, np.asarray(encoding.matrix()))  # fixed
  assert 1.0 < np.std(b) < 6.0  # scale 3
  x = np.asarray(jax.random.uniform(jax.random.PRNGKey(0), (4, 6, 3), minval=-1.5, maxval=1.5))
  angles = np.array([[[2 * np.pi * sum(p[d] * row[d] for d in range(3)) for row in b]
                      for p in ray] for ray in x.astype(np.float64)])  # [4, 6, 5]
  got = np.asarray(encoding.features(None, x))
  assert got.shape == (4, 6, 10) == (4, 6, encoding.width(3))
  np.testing.assert_allclose(got, np.concatenate([np.sin(angles), np.cos(angles)], -1),
                             atol=1e-4)


def test_the_docs_encoding_trains_and_restores_from_its_config_file(doc_files, tmp_path):
  config = _loaded(doc_files)
  field = builders.make_field(config)
  assert type(field.network).__name__ == "NerfMLP"  # the encoding's own network
  assert type(field.network.encoding).__name__ == "FourierFeatures"
  assert field.network.encoding.settings.scale == 4.0 and field.coarse_to_fine_stages == 0
  params = field.init(jax.random.PRNGKey(0))
  assert sorted(params) == ["layer_0", "layer_1", "output"]  # B is a constant, not a parameter
  assert params["layer_0"]["kernel"].shape == (2 * 8, 16)  # gamma: 2 x features inputs
  entries = signature.model_signature(config)
  assert entries["encoding"] == "fourier" and entries["fourier_features"] == 8
  assert entries["fourier_seed"] == 0 and "network" not in entries

  workdir = str(tmp_path / "run")
  train_lib.train_and_evaluate(config, workdir)
  restored, state = experiment.restore(workdir)
  assert int(state.step) == 20
  assert type(restored.renderer.field.network.encoding).__name__ == "FourierFeatures"
  trained = jax.tree_util.tree_map(np.asarray, state.params["coarse"])
  initial = signature.init_state(experiment.setup(config)).params["coarse"]
  assert not np.allclose(trained["layer_0"]["kernel"], initial["layer_0"]["kernel"])  # learnt


def test_the_docs_encoding_under_another_network_and_a_registered_name(doc_files):
  config = _loaded(doc_files)
  config.model.network = "lattice"  # the grids' tiny head on the Fourier features
  field = builders.make_field(config)
  assert type(field.network).__name__ == "LatticeHead"
  assert field.init(jax.random.PRNGKey(0))["hidden"]["kernel"].shape == (16, 16)
  assert signature.model_signature(config)["network"] == "lattice"
  registry.ENCODINGS.register("fourier_for_test", "my_encodings.fourier")
  try:
    assert "fourier_for_test" in registry.ENCODINGS.names()
    assert (registry.ENCODINGS.lookup("fourier_for_test")
            is registry.ENCODINGS.lookup("my_encodings.fourier"))
  finally:
    registry.ENCODINGS.unregister("fourier_for_test")


def test_the_docs_encoding_names_a_wrong_setting_or_name(doc_files):
  config = _loaded(doc_files)
  config.model.fourier.scael = 2.0  # misspelt: an error naming it
  with pytest.raises(ValueError, match="model.fourier has no setting 'scael'"):
    builders.make_field(config)
  config = _loaded(doc_files)
  config.model.fourier.scale = -1.0  # checked in the settings' __post_init__
  with pytest.raises(ValueError, match="config.model.fourier needs features >= 1 and scale > 0"):
    builders.make_field(config)
  config.model.encoding = "no_such_encoding"
  known = ", ".join(registry.ENCODINGS.names())
  with pytest.raises(ValueError, match=f"config.model.encoding must be one of {known} or a "
                     "module path, got 'no_such_encoding'"):
    builders.make_field(config)
