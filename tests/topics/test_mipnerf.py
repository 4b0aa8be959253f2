"""configs/mipnerf.py shrunk: it trains (rays made per step with their radii), its PSNR
covers at least half the way from the untrained model's to the mean colour's, and its checkpoint
restores to the trained parameters and renders, bit for bit, what the trained model renders;
its scores again are metrics.json's. (Beating the trivial answers takes hundreds of steps at
this size, as for configs/debug.py: conftest's shared run.)"""

import json

import jax
import numpy as np

from nerf_jax.render import image_renderer
from nerf_jax.run import builders, experiment, train_lib
from tests.helpers import small_config

# mip-NeRF's config at the tests' size: 6 + 1 views of 16², 8 + 8 samples, a narrow MLP.
TINY_MIPNERF = {"data.num_views": 6, "data.image_size": 16, "data.holdout_from": 5,
                "num_samples": 8, "num_fine_samples": 8, "pos_encode_dims": 6,
                "model.width": 32, "model.depth": 3, "model.skip_layers": (), "train.lr": 5e-3,
                "train.batch_rays": 256, "train.max_steps": 30, "train.log_every": 30,
                "train.checkpoint_every": 30, "train.warmup_steps": 0, "render.chunk": 256}


class _LastVariables:
  """A watcher (train_and_evaluate's watchers) keeping the variables after the last step."""

  def __init__(self, exp, workdir, main):
    del exp, workdir, main
    self.variables = None

  def after_step(self, step, variables_fn):
    del step
    self.variables = jax.device_get(variables_fn())

  def close(self):
    pass


def test_mipnerf_trains_and_restores(tmp_path):
  config = small_config(TINY_MIPNERF, base="mipnerf")
  workdir = tmp_path / "mipnerf"
  kept = []

  def keep_last(*args):
    kept.append(_LastVariables(*args))
    return kept[-1]
  result = train_lib.train_and_evaluate(config, str(workdir), watchers=[keep_last])
  trained = kept[0].variables
  exp, state = experiment.restore(str(workdir))
  assert exp.renderer.field.cones and exp.renderer.networks == ("coarse",)
  assert builders.make_train_data(exp).with_radii  # the train step's rays carry radii
  assert exp.rays(exp.test_ds.poses[0]).radii is not None  # so do the evaluated images'
  assert result["steps"] == 30 and len(exp.test_ds) == 1
  # The checkpoint holds the trained parameters, bit for bit, and renders what they render.
  restored = jax.device_get(state.variables)
  assert jax.tree_util.tree_structure(restored) == jax.tree_util.tree_structure(trained)
  for a, b in zip(jax.tree_util.tree_leaves(trained), jax.tree_util.tree_leaves(restored)):
    np.testing.assert_array_equal(a, b)
  draw = image_renderer.make_image_renderer(exp.renderer, exp.image)
  rays = exp.rays(exp.test_ds.poses[0])
  np.testing.assert_array_equal(draw(restored)(rays)["rgb"], draw(trained)(rays)["rgb"])
  # Trained: at least half the way from the untrained model's PSNR to the mean colour's (the
  # best constant image; 30 steps of this size do not reach it: module docstring).
  untrained = builders.make_evaluator(exp)(exp.renderer.init(jax.random.PRNGKey(config.seed)))
  truth = np.float64(exp.test_ds.images[0])
  mean_colour = -10 * np.log10(np.mean((truth - truth.reshape(-1, 3).mean(0)) ** 2))
  floor = untrained["psnr"] + 0.5 * (mean_colour - untrained["psnr"])
  assert mean_colour - untrained["psnr"] > 3.0  # the floor is above the untrained model's
  assert result["psnr"] > floor, (result["psnr"], untrained["psnr"], mean_colour)
  again = builders.make_evaluator(exp)(state.variables)
  stored = json.loads((workdir / "metrics.json").read_text())
  assert again["per_view"] == stored["per_view"]
