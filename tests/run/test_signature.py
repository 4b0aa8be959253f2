"""Checkpoints of earlier versions restore: the occupancy grid once lived in params['occupancy'],
with Adam moments of its own (always zero: nothing trained it); upgrade_state_dict
moves it to the buffers, and the run resumes exactly where it stood."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import serialization

from nerf_jax.run import builders, experiment
from nerf_jax.train import optimizer
from nerf_jax.run.signature import init_state, model_signature, state_template
from nerf_jax.train.state import upgrade_state_dict
from nerf_jax.train import checkpoints
from tests.helpers import params_equal
from tests.helpers import small_config

# A grid model with the occupancy grid (refreshed every step), as test_occupancy trains it.
OCCUPANCY = {"model.encoding": "grid", "model.grid.resolutions": (8, 16),
             "model.grid.features": 2, "model.density_activation": "softplus",
             "data.scene_bound": 1.5, "model.grid_bound": 1.5, "occupancy.enabled": True,
             "occupancy.resolution": 12, "occupancy.candidates": 64,
             "occupancy.update_every": 1}


def _old_style(state_dict):
  """Brute force, the inverse of the upgrade: today's state dict as the earlier version saved
  it: the grid in params['occupancy'], zero Adam moments for it beside the networks', no
  buffers."""
  old = jax.tree_util.tree_map(np.asarray, state_dict)
  grid = old.pop("buffers")["occupancy"]
  del old["ema"]  # saved before the weights' moving average existed
  old["params"]["occupancy"] = grid
  adam = old["opt_state"]["0"]
  assert set(adam) == {"count", "mu", "nu"} and set(adam["mu"]) == {"coarse"}
  for moment in ("mu", "nu"):
    adam[moment]["occupancy"] = np.zeros_like(grid)
  return old


@pytest.fixture(scope="module")
def trained():
  """(config, Experiment, TrainState after 3 steps: the grid and the moments are not zero)."""
  config = small_config(OCCUPANCY)
  exp = experiment.setup(config)
  step, data = builders.make_train_step(exp), builders.make_train_data(exp)
  state = init_state(exp)
  for _ in range(3):
    state, _ = step(state, data, jax.random.PRNGKey(0))
  assert float(jnp.max(state.buffers["occupancy"])) > 0
  return config, exp, jax.device_get(state)


def test_an_old_checkpoint_restores_into_the_new_train_state(trained, tmp_path):
  config, exp, state = trained
  old = _old_style(serialization.to_state_dict(state))
  workdir = str(tmp_path / "old")
  (tmp_path / "old").mkdir()
  (tmp_path / "old" / "config.json").write_text(config.to_json())
  signature = model_signature(config)
  checkpoints.save(workdir, 3, old, signature)  # what the earlier version wrote
  path = checkpoints.latest_path(workdir)
  with pytest.raises(checkpoints.CheckpointError):  # not restorable as it is ...
    checkpoints.restore(path, state_template(exp), signature)
  _, restored = experiment.restore(workdir)  # ... but through the upgrade
  assert "occupancy" not in restored.params
  assert int(restored.step) == 3 and int(restored.bad_step) == -1
  assert params_equal(restored.params, state.params)
  assert params_equal(restored.buffers, state.buffers)
  assert params_equal(restored.opt_state, state.opt_state)
  assert (jax.tree_util.tree_structure(restored) ==
          jax.tree_util.tree_structure(state_template(exp)))


def test_upgrade_leaves_a_current_state_dict_and_one_without_occupancy_alone(trained):
  _, _, state = trained
  current = serialization.to_state_dict(state)
  assert upgrade_state_dict(current) is current
  # An old run without occupancy: params hold only the networks; buffers come back empty.
  old = jax.tree_util.tree_map(np.asarray, current)
  del old["buffers"]
  old["params"].pop("occupancy", None)
  upgraded = upgrade_state_dict(old)
  assert upgraded["buffers"] == {} and set(upgraded["params"]) == {"coarse"}
  structure = jax.tree_util.tree_structure
  assert structure(upgraded["opt_state"]) == structure(current["opt_state"])
  assert params_equal(upgraded["opt_state"], current["opt_state"])


def test_a_run_saved_before_appearance_lr_keeps_what_it_trained_with():
  """A config.json without train.appearance_lr (saved before it existed) completes to what
  that run did: codes at train.lr, in the field's Adam (the checkpoint's state); a current
  save keeps its own value, and its codes have an Adam of their own."""
  from nerf_jax.run import config_lib
  saved = small_config({"model.appearance_dims": 4, "train.pose_refinement": True}).to_dict()
  del saved["train"]["appearance_lr"]
  old = config_lib.complete(saved)
  assert old.train.appearance_lr == old.train.lr
  state = init_state(experiment.setup(old))
  assert set(state.opt_state.inner_states) == {"field", "poses"}  # codes in the field's Adam
  current = config_lib.complete(small_config({"model.appearance_dims": 4}).to_dict())
  state = init_state(experiment.setup(current))
  assert set(state.opt_state.inner_states) == {"field", "codes"}
  assert current.train.appearance_lr == 3e-4 != current.train.lr


def test_pose_refinement_keeps_the_optimiser_state_its_checkpoints_saved():
  """Brute force: the optimiser state of a pose-refinement run without codes has the structure
  of the one checkpoints were saved with (two Adams, labels by top-level name)."""
  import optax
  config = small_config({"train.pose_refinement": True, "data.scene": "perturbed"})
  exp = experiment.setup(config)
  state = init_state(exp)
  schedule = optimizer.make_schedule(builders.optimizer_settings(config))
  saved_style = optax.multi_transform(
      {"field": optax.adam(schedule), "poses": optax.adam(schedule)},
      lambda params: {k: "poses" if k == "poses" else "field" for k in params})
  assert (jax.tree_util.tree_structure(state.opt_state) ==
          jax.tree_util.tree_structure(saved_style.init(state.params)))


def test_a_run_saved_before_pose_prior_keeps_its_corrections_free():
  from nerf_jax.run import config_lib
  saved = small_config({"train.pose_refinement": True}).to_dict()
  del saved["loss"]  # before loss sections, and before train.pose_prior (their old home)
  assert config_lib.complete(saved).loss.pose_prior.weight == 0.0
  saved["train"]["pose_prior"] = 2.0  # a run saved with the prior, under its old name
  assert config_lib.complete(saved).loss.pose_prior.weight == 2.0
  current = config_lib.complete(small_config({"train.pose_refinement": True}).to_dict())
  assert (current.loss.pose_prior.weight == config_lib.load("default").loss.pose_prior.weight
          > 0)
