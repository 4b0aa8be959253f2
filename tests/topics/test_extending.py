"""docs/extending.md's walk-through, run as written: its encoding module and config section are
copied from the doc into a temporary package, trained a few steps through the library's own
training job, and restored; no file of the tree is touched."""

import pathlib
import re

import jax
import ml_collections
import numpy as np
import pytest

from nerf_jax.fields import registry
from nerf_jax.run import experiment, train_lib
from tests.helpers import ROOT, TINY_GRID, small_config

DOC = pathlib.Path(ROOT) / "docs" / "extending.md"


def doc_block(name):
  """The code block of docs/extending.md marked `<!-- tests/topics/test_extending.py: name -->`."""
  marker = re.escape(f"<!-- tests/topics/test_extending.py: {name} -->")
  found = re.search(marker + r"\s*```python\n(.*?)```", DOC.read_text(), re.S)
  assert found, f"docs/extending.md lost its {name} block"
  return found.group(1)


@pytest.fixture
def triplane_config(tmp_path, monkeypatch):
  """A tiny config of configs/fast.py with the doc's tri-plane family (a package in tmp_path)."""
  package = tmp_path / "my_fields"
  package.mkdir()
  (package / "__init__.py").write_text("")
  (package / "triplane.py").write_text(doc_block("module"))
  monkeypatch.syspath_prepend(str(tmp_path))
  config = small_config(TINY_GRID, base="fast")  # 30 steps, checkpointed at the end
  exec(doc_block("config"), {"config": config, "ml_collections": ml_collections})  # pylint: disable=exec-used
  config.model.triplane.resolution = 16
  return config


def test_the_docs_encoding_trains_and_restores_from_its_config_section(triplane_config, tmp_path):
  config = triplane_config
  exp = experiment.setup(config)
  network = exp.renderer.field.network
  assert type(network).__name__ == "TriPlaneNeRF" and network.resolution == 16
  assert exp.renderer.field.pos_encode_dims is None  # raw positions: the planes encode them
  params = experiment.init_state(exp).params["coarse"]
  assert sorted(k for k in params if k.startswith("plane_")) == ["plane_01", "plane_02", "plane_12"]
  assert params["plane_01"].shape == (16, 16, 8)
  signature = experiment.model_signature(config)
  assert signature["encoding"] == "triplane" and signature["triplane_resolution"] == 16
  # Its planes take the total variation (its table_axes), as the built-in tables do.
  config.loss.total_variation.weight = 0.1
  tv = [t for t in experiment.loss_terms(config, exp.renderer) if hasattr(t, "table_axes")]
  assert dict(tv[0].table_axes) == {"plane_": 2}
  config.loss.total_variation.weight = 0.0

  workdir = str(tmp_path / "run")
  train_lib.train_and_evaluate(config, workdir)
  restored, state = experiment.restore(workdir)
  assert int(state.step) == 30
  assert type(restored.renderer.field.network).__name__ == "TriPlaneNeRF"
  trained = jax.tree_util.tree_map(np.asarray, state.params["coarse"])
  assert not np.allclose(trained["plane_01"], params["plane_01"])  # the planes learnt


def test_a_registered_name_and_a_wrong_one(triplane_config):
  registry.register("triplane_for_test", "my_fields.triplane")
  try:
    assert registry.lookup("triplane_for_test") is registry.lookup("my_fields.triplane")
  finally:
    registry._MODULES.pop("triplane_for_test")  # pylint: disable=protected-access
  triplane_config.model.triplane.resoluton = 8  # misspelt: an error naming it
  with pytest.raises(ValueError, match="model.triplane has no setting 'resoluton'"):
    experiment.make_field(triplane_config)
  triplane_config.model.encoding = "no_such_family"
  with pytest.raises(ValueError, match="posenc, grid, hash, tensorf or a module path"):
    experiment.make_field(triplane_config)
