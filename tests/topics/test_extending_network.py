"""docs/extending.md's network walk-through, run as written: its module and its config file are
written verbatim into new files (2 files, no edit of the tree), the config file is loaded by the
library's own loader, trained, restored in a new process that never ran the config file (so
the name it registered is unknown there), and resumed under a changed setting."""

import json
import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from nerf_jax.fields import registry
from nerf_jax.run import builders, config_lib, experiment, signature, train_lib
from nerf_jax.train import checkpoints
from tests import helpers

SHRINK = {"data.num_views": 6, "data.image_size": 16, "data.holdout_from": 5, "num_samples": 16,
          "model.width": 16, "train.batch_rays": 128, "train.max_steps": 10,
          "train.log_every": 10, "train.checkpoint_every": 10, "render.after_training": False,
          "render.video_frames": 0, "render.chunk": 256, "render.march_grid": 16}


@pytest.fixture
def doc_files(tmp_path, monkeypatch):
  """The doc's module (my_networks/resmlp.py) and config file (my_config.py) in tmp_path, which
  goes on sys.path as the doc's PYTHONPATH; the name the config file registers is forgotten
  afterwards. Returns the config file's path."""
  path = helpers.write_walkthrough(tmp_path, "tests/topics/test_extending_network.py",
                                   "my_networks/resmlp.py")
  monkeypatch.syspath_prepend(str(tmp_path))
  yield path
  registry.NETWORKS.unregister("resmlp")


def _loaded(path, **overrides):
  config = config_lib.load(path)
  for field, value in {**SHRINK, **overrides}.items():
    config_lib.set_field(config, field, value)
  return config


def test_the_docs_network_is_built_from_its_own_section(doc_files):
  config = _loaded(doc_files)
  field = builders.make_field(config)
  assert type(field.network).__name__ == "ResidualMLP"
  assert field.network.settings.blocks == 3 and field.network.shared.width == 16
  params = field.init(jax.random.PRNGKey(0))
  # Input layer, 3 blocks of 2, density and colour heads: 1 + 6 + 2 dense layers.
  assert len(params) == 9 and params["Dense_0"]["kernel"].shape == (3 + 3 * 2 * 10, 16)
  entries = signature.model_signature(config)
  assert entries["network"] == "resmlp" and entries["resmlp_blocks"] == 3


def test_the_docs_network_refuses_a_misspelt_or_wrong_setting(doc_files):
  config = _loaded(doc_files)
  config.model.resmlp.blokcs = 4
  with pytest.raises(ValueError, match="config.model.resmlp has no setting 'blokcs'"):
    builders.make_field(config)
  config = _loaded(doc_files, **{"model.resmlp.blocks": 0})
  with pytest.raises(ValueError, match=r"config.model.resmlp.blocks=0: use 1 or more"):
    builders.make_field(config)


def _restore_in_new_process(workdir, tmp_path):
  """What a new process (render.py) restores from `workdir`: the network's type and one
  rendered pixel's colour, with the doc's module importable but its config file never run."""
  script = ("import sys, json, numpy as np\n"
            "from nerf_jax.fields import registry\n"
            "from nerf_jax.run import experiment\n"
            "assert 'resmlp' not in registry.NETWORKS.names()\n"
            f"exp, state = experiment.restore({workdir!r})\n"
            "leaves = [np.asarray(x).ravel()[:3].tolist() for x in\n"
            "          __import__('jax').tree_util.tree_leaves(state.params)]\n"
            "print(json.dumps([type(exp.renderer.field.network).__name__, int(state.step),\n"
            "                  leaves]))\n")
  env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), helpers.ROOT]))
  done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                        text=True, timeout=300, check=False)
  assert done.returncode == 0, done.stderr[-2000:]
  return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_registered_network_trains_restores_in_a_new_process_and_resumes_by_signature(
    doc_files, tmp_path):
  config = _loaded(doc_files)
  workdir = str(tmp_path / "run")
  train_lib.train_and_evaluate(config, workdir)
  with open(os.path.join(workdir, "config.json")) as f:
    assert json.load(f)["model"]["network"] == "my_networks.resmlp"  # the module, not the name
  state = experiment.restore(workdir)[1]
  kind, step, leaves = _restore_in_new_process(workdir, tmp_path)
  assert (kind, step) == ("ResidualMLP", 10)
  trained = [np.asarray(x).ravel()[:3].tolist() for x in jax.tree_util.tree_leaves(state.params)]
  assert leaves == trained  # the same parameters, bit for bit

  changed = _loaded(doc_files, **{"model.resmlp.blocks": 4, "train.max_steps": 20})
  with pytest.raises(checkpoints.CheckpointError, match="resmlp_blocks: checkpoint 3 vs config 4"):
    train_lib.train_and_evaluate(changed, workdir)
