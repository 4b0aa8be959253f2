"""Each per-scene config switches on what its scene calls for, and trains for a few steps."""

import importlib

import numpy as np
import pytest

from nerf_jax import train_lib

SCENES = ["diffuse", "glossy", "fog", "white", "forward"]


def _shrunk(name):
  config = importlib.import_module(f"nerf_jax.configs.scenes.{name}").get_config()
  config.data.num_views, config.data.image_size, config.data.holdout_from = 6, 16, 5
  config.model.depth, config.model.width, config.model.skip_layers = 2, 16, (0,)
  config.num_samples = 8
  config.num_fine_samples = min(config.num_fine_samples, 8)
  config.train.max_steps, config.train.batch_rays, config.train.log_every = 3, 64, 3
  config.render.after_training = False
  return config


def test_components_match_the_scene():
  load = lambda n: importlib.import_module(f"nerf_jax.configs.scenes.{n}").get_config()
  assert not load("diffuse").model.view_dependent and load("diffuse").num_fine_samples == 0
  assert load("glossy").model.view_dependent
  assert load("fog").num_fine_samples > 0
  assert load("white").data.background == "white"
  assert load("forward").data.ndc


@pytest.mark.parametrize("name", SCENES)
def test_scene_config_trains(name, tmp_path):
  result = train_lib.train_and_evaluate(_shrunk(name), str(tmp_path / name))
  assert result["steps"] == 3 and np.isfinite(result["psnr"])
