"""Shared test scaffolding: the shrunk config, restoring a run's parameters, comparing them.

Markers: `slow` (a test that trains or spawns processes for more than ~10 s). The README's test
command runs everything; `python -m pytest -m "not slow"` is the quick loop while editing.
"""

import jax
import numpy as np
import pytest

from nerf_jax import experiment
from nerf_jax.configs import debug


def tiny_config(**train):
  """configs/debug.py (24×24 views, a small MLP, 20 steps) with no rendering after training;
  `train` overrides config.train fields."""
  config = debug.get_config()
  config.render.after_training = False
  for k, v in train.items():
    config.train[k] = v
  return config


def restored_params(workdir):
  """The parameters of the newest checkpoint in `workdir`."""
  return experiment.restore(str(workdir))[1].params


def params_equal(a, b):
  """Whether two parameter trees hold exactly the same arrays."""
  leaves = zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
  return all(np.array_equal(x, y) for x, y in leaves)


@pytest.fixture
def config():
  """A fresh `tiny_config()` for each test."""
  return tiny_config()
