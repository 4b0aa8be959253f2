"""Each per-scene config switches on what its scene calls for, and trains for a few steps."""

import numpy as np
import pytest

from nerf_jax.run import builders, config_lib
from nerf_jax.run import train_lib
from tests.helpers import small_config

SCENES = ["diffuse", "glossy", "fog", "white", "forward", "crowd"]


# configs/scenes/<name>.py shrunk to 3 steps (at most 8 fine samples: see the test).
SHRUNK = {"data.num_views": 6, "data.image_size": 16, "data.holdout_from": 5, "model.depth": 2,
          "model.width": 16, "model.skip_layers": (0,), "num_samples": 8, "train.max_steps": 3,
          "train.batch_rays": 64, "train.log_every": 3}


def test_components_match_the_scene():
  load = lambda n: config_lib.load(f"scenes/{n}")
  assert not load("diffuse").model.view_dependent and load("diffuse").num_fine_samples == 0
  assert load("glossy").model.view_dependent
  assert load("fog").num_fine_samples > 0
  assert load("white").data.background == "white"
  assert load("forward").data.ndc
  crowd = load("crowd")  # the switch alone: patches of 16 follow
  batch = builders.batch_settings(crowd)
  assert crowd.loss.robust.weight > 0 and crowd.model.appearance_dims > 0
  assert (batch.batching, batch.patch_size) == ("patches", 16)
  landmark = load("landmark")  # an unbounded capture with looks: the box from the data, codes
  assert landmark.data.scene_bound == -1 and landmark.model.appearance_dims > 0


@pytest.mark.parametrize("name", SCENES)
def test_scene_config_trains(name, tmp_path):
  fine = min(config_lib.load(f"scenes/{name}").num_fine_samples, 8)
  config = small_config(SHRUNK, base=f"scenes/{name}", num_fine_samples=fine)
  result = train_lib.train_and_evaluate(config, str(tmp_path / name))
  assert result["steps"] == 3 and np.isfinite(result["psnr"])
