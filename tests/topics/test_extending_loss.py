"""docs/extending.md's loss-term walk-through, run as written: its term module and its complete
config file are copied from the doc into a temporary folder, the config is loaded by the
library's own loader (nothing injected), and a few steps are trained through the library's
training job with the term and without it; no file of the tree is touched."""

import json
import sys

import jax
import numpy as np
import pytest

from nerf_jax.run import builders, experiment, train_lib
from nerf_jax.train import losses
from tests import helpers
from tests.helpers import TINY_GRID, small_config

# The tiny grid run, shortened: 6 steps, logged every 3.
STEPS = {**TINY_GRID, "train.max_steps": 6, "train.log_every": 3, "train.checkpoint_every": 6}
THIS = "tests/topics/test_extending_loss.py"


@pytest.fixture
def config_file(tmp_path, monkeypatch):
  """The path of the doc's config file, its term module a package beside it on sys.path."""
  path = helpers.write_walkthrough(tmp_path, THIS, "my_losses/opacity.py")
  monkeypatch.syspath_prepend(str(tmp_path))
  yield path
  for name in [n for n in sys.modules if n == "my_losses" or n.startswith("my_losses.")]:
    del sys.modules[name]


def _train(config, workdir):
  """(metrics.jsonl's records, the trained coarse parameters) of a run of `config`."""
  train_lib.train_and_evaluate(config, workdir)
  records = [json.loads(line) for line in open(f"{workdir}/metrics.jsonl")]
  _, state = experiment.restore(workdir)
  return records, jax.tree_util.tree_map(np.asarray, state.params["coarse"])


def test_the_docs_loss_term_is_logged_and_changes_training(config_file, tmp_path):
  # The doc's file as the library loads it (small_config: config_lib.load, then tiny sizes).
  config = small_config(STEPS, base=config_file)
  assert config.loss.terms[-1] == "my_losses.opacity" and config.loss.opacity.weight == 1e-3
  config.loss.opacity.weight = 0.5  # a clear effect in 6 steps
  records, trained = _train(config, str(tmp_path / "with"))
  logged = [r for r in records if "opacity/mean" in r]
  assert len(logged) == 2  # steps 3 and 6, under the term's name
  assert all(0.0 <= r["opacity/mean"] <= 1.0 for r in logged)

  config.loss.opacity.weight = 0.0  # off: the term is left out
  records, untouched = _train(config, str(tmp_path / "without"))
  assert not any("opacity/mean" in r for r in records)
  assert not all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(trained),
                                                       jax.tree_util.tree_leaves(untouched)))


def test_the_docs_term_checks_its_settings_and_registers_by_name(config_file):
  config = small_config(STEPS, base=config_file)
  config.loss.opacity.weight = -1.0
  with pytest.raises(ValueError, match=r"config.loss.opacity.weight=-1.0"):
    builders.loss_terms(config, builders.make_ray_renderer(config))
  losses.REGISTRY.register("opacity_for_test", "my_losses.opacity")
  try:
    assert losses.REGISTRY.lookup("opacity_for_test") is losses.REGISTRY.lookup(
        "my_losses.opacity")
  finally:
    losses.REGISTRY.unregister("opacity_for_test")
