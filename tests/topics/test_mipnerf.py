"""configs/mipnerf.py shrunk: it trains (rays made per step with their radii, parameters
finite and moved), and its checkpoint restores to the same scores. (Beating the trivial answers
takes hundreds of steps at this size, as for configs/debug.py: conftest's shared run.)"""

import json

import jax
import numpy as np

from nerf_jax.run import components, experiment, train_lib
from tests.helpers import small_config

# mip-NeRF's config at the tests' size: 6 + 1 views of 16², 8 + 8 samples, a narrow MLP.
TINY_MIPNERF = {"data.num_views": 6, "data.image_size": 16, "data.holdout_from": 5,
                "num_samples": 8, "num_fine_samples": 8, "pos_encode_dims": 6,
                "model.width": 32, "model.depth": 3, "model.skip_layers": (), "train.lr": 5e-3,
                "train.batch_rays": 256, "train.max_steps": 30, "train.log_every": 30,
                "train.checkpoint_every": 30, "train.warmup_steps": 0, "render.chunk": 256}


def test_mipnerf_trains_and_restores(tmp_path):
  config = small_config(TINY_MIPNERF, base="mipnerf")
  workdir = tmp_path / "mipnerf"
  result = train_lib.train_and_evaluate(config, str(workdir))
  exp, state = experiment.restore(str(workdir))
  assert exp.renderer.field.cones and exp.renderer.networks == ("coarse",)
  assert components.make_train_data(exp).with_radii  # the train step's rays carry radii
  assert exp.rays(exp.test_ds.poses[0]).radii is not None  # so do the evaluated images'
  assert np.isfinite(result["psnr"]) and result["steps"] == 30
  init = exp.renderer.init(jax.random.PRNGKey(config.seed))["params"]
  trained = state.variables["params"]
  leaves = list(zip(jax.tree_util.tree_leaves(init), jax.tree_util.tree_leaves(trained)))
  assert all(np.all(np.isfinite(b)) for _, b in leaves)
  assert not all(np.array_equal(a, b) for a, b in leaves)  # trained
  again = components.make_evaluator(exp)(state.variables)
  stored = json.loads((workdir / "metrics.json").read_text())
  assert again["per_view"] == stored["per_view"]
