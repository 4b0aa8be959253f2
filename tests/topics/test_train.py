"""End to end: training improves quality, checkpoints restore exactly, runs resume and stop safely."""

import json
import os
import subprocess
import sys

import imageio.v2 as imageio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import camera_paths
from nerf_jax.render import background
from nerf_jax.run import builders, config_lib, experiment, outputs
from nerf_jax.run.signature import init_state, model_signature, state_template
from nerf_jax.train import checkpoints, train_batches
from nerf_jax.run import train_lib
from nerf_jax.cameras.rays import Rays
from tests.helpers import params_equal as _params_equal
from tests.helpers import restored_variables
from tests.helpers import small_config

from tests.helpers import ROOT


# Quality after training (against trivial answers, depth) is tests/topics/test_quality.py, on the
# shared trained run.


def test_resume_continues_at_the_right_step_and_matches_an_uninterrupted_run(tmp_path):
  config = lambda: small_config({"train.max_steps": 20})
  full = train_lib.train_and_evaluate(config(), str(tmp_path / "full"))
  # A run killed after its step-10 checkpoint: the same config, only that checkpoint on disk.
  split = str(tmp_path / "split")
  train_lib.train_and_evaluate(config(), split)
  os.remove(os.path.join(checkpoints.checkpoint_dir(split), "ckpt_20.msgpack"))
  assert checkpoints.list_steps(split) == [10]
  resumed = train_lib.train_and_evaluate(config(), split)
  assert resumed["steps"] == 20
  lines = [json.loads(l) for l in open(os.path.join(split, "metrics.jsonl"))]
  # Each run ends with its final-eval record; the resumed run logged only step 20 and its eval.
  assert [(r["step"], "final" in r) for r in lines] == [(10, False), (20, False), (20, True),
                                                        (20, False), (20, True)]
  v_full, v_split = restored_variables(tmp_path / "full"), restored_variables(split)
  assert _params_equal(v_full, v_split)  # bitwise: batches are drawn from fold_in(key, step)
  assert resumed["psnr"] == full["psnr"]


def test_checkpoint_restore_render_gives_the_same_image(trained_run):
  workdir, _ = trained_run  # conftest's shared run, read only
  exp, state = experiment.restore(str(workdir))
  again = builders.make_evaluator(exp)(state.variables)
  stored = json.loads((workdir / "metrics.json").read_text())
  assert again["per_view"] == stored["per_view"]


def test_same_seed_same_parameters(tmp_path):
  train_lib.train_and_evaluate(small_config({"train.max_steps": 5}), str(tmp_path / "a"))
  train_lib.train_and_evaluate(small_config({"train.max_steps": 5}), str(tmp_path / "b"))
  assert _params_equal(restored_variables(tmp_path / "a"), restored_variables(tmp_path / "b"))


def test_non_finite_loss_stops_with_step_and_checkpoint_named(tmp_path):
  config = small_config({"train.max_steps": 20, "train.log_every": 5,
                         "train.checkpoint_every": 5,
                         "train.lr": 1e30,  # parameters overflow within a few steps
                         "train.lr_final": 1e30})
  with pytest.raises(experiment.TrainingError, match=r"non-finite .* at step \d+.*checkpoint"):
    train_lib.train_and_evaluate(config, str(tmp_path / "nan"))


def test_no_checkpoint_is_written_after_a_non_finite_step(tmp_path):
  # Checkpoints (every 3) fall between log steps (every 7): the check must not wait for a log.
  config = small_config({"train.max_steps": 20, "train.log_every": 7,
                         "train.checkpoint_every": 3, "train.lr": 1e30, "train.lr_final": 1e30})
  workdir = str(tmp_path / "nan")
  with pytest.raises(experiment.TrainingError, match="non-finite") as info:
    train_lib.train_and_evaluate(config, workdir)
  template = state_template(experiment.setup(config))
  for step in checkpoints.list_steps(workdir):
    path = os.path.join(checkpoints.checkpoint_dir(workdir), f"ckpt_{step}.msgpack")
    state = checkpoints.restore(path, template, model_signature(config))
    assert int(state.bad_step) < 0, step
    assert all(np.isfinite(x).all() for x in jax.tree_util.tree_leaves(state.params))
  named = checkpoints.latest_path(workdir) or "none yet"
  assert named in str(info.value)


def test_incompatible_checkpoint_is_refused(tmp_path):
  workdir = str(tmp_path / "run")
  train_lib.train_and_evaluate(small_config({"train.max_steps": 2}), workdir)
  wider = small_config({"train.max_steps": 4})
  wider.model.width = 48
  with pytest.raises(checkpoints.CheckpointError, match="incompatible config.*width"):
    train_lib.train_and_evaluate(wider, workdir)
  assert checkpoints.list_steps(workdir) == [2]  # nothing overwritten


@pytest.mark.slow  # wall-clock
def test_wall_clock_budget_stops_early(tmp_path):
  config = small_config({"train.max_steps": 100000, "train.max_seconds": 3.0})
  result = train_lib.train_and_evaluate(config, str(tmp_path / "budget"))
  assert 0 < result["steps"] < 100000
  assert checkpoints.list_steps(str(tmp_path / "budget"))[-1] == result["steps"]


def test_epoch_image_order_visits_every_image_once_per_epoch():
  config = small_config()
  config.train.batching = "images"
  config.train.images_per_step = 3
  config.train.image_order = "epochs"
  num_images = 10  # debug config: views 0-9 train; 3 steps of 3 per epoch, one image dropped
  ids = jnp.broadcast_to(jnp.arange(num_images, dtype=jnp.float32)[:, None, None], (10, 2, 3))
  rays = Rays(ids, ids, ids, ids[..., 0], ids[..., 0])
  data = train_batches.TrainData(rays, ids, ids[..., 0])  # every pixel holds its image id
  run_key = jax.random.PRNGKey(7)
  draw = jax.jit(lambda step: train_batches.draw_batch(data, builders.batch_settings(config), None, step, run_key).rgb)
  epochs = []
  for epoch in range(3):
    ids = [np.asarray(draw(epoch * 3 + s))[::2, 0].astype(int) for s in range(3)]
    seen = np.concatenate(ids)
    assert len(set(seen.tolist())) == 9 and set(seen.tolist()) <= set(range(num_images))
    epochs.append(seen.tolist())
  assert epochs[0] != epochs[1]  # a new shuffle each epoch


def test_whole_image_batching_draws_whole_images():
  config = small_config()
  config.train.batching = "images"
  config.train.images_per_step = 2
  exp = experiment.setup(config)
  train_ds = exp.train_ds
  data = builders.make_train_data(exp)
  rgb = train_batches.draw_batch(data, builders.batch_settings(config), jax.random.PRNGKey(0)).rgb
  pixels = train_ds.height * train_ds.width
  assert rgb.shape == (2 * pixels, 3)
  flat = np.asarray(data.rgb)
  matches = [i for i in range(len(train_ds)) if np.array_equal(flat[i], rgb[:pixels])]
  assert len(matches) == 1


def _run(args, cwd):
  env = dict(os.environ, PYTHONPATH=ROOT)
  return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True,
                        text=True, timeout=300)


@pytest.mark.slow  # train.py and render.py in processes
def test_train_and_render_entry_points(tmp_path):
  workdir = str(tmp_path / "cli")
  res = _run(["train.py", "--config=configs/debug.py", f"--workdir={workdir}",
              "--config.train.max_steps=4"], ROOT)
  assert res.returncode == 0, res.stderr[-2000:]
  # The video when an mp4 writer is installed; else one line says why, and the run stands.
  missing = outputs.video_writer_missing()
  assert os.path.exists(os.path.join(workdir, "video", "rgb.mp4")) == (missing is None)
  assert missing is None or missing in res.stdout
  assert os.path.exists(os.path.join(workdir, "eval", "view_000.png"))
  res = _run(["render.py", f"--workdir={workdir}", "--mode=eval"], ROOT)
  assert res.returncode == 0 and "test PSNR" in res.stdout, res.stderr[-2000:]


@pytest.mark.slow  # train.py in a process
def test_train_without_flags_uses_default_config_and_workdir(tmp_path):
  """`python train.py` as the README runs it: no --config, no --workdir (overrides keep it tiny)."""
  res = _run([os.path.join(ROOT, "train.py"), "--config.train.max_steps=2",
              "--config.data.image_size=16", "--config.data.num_views=5",
              "--config.render.after_training=False"], str(tmp_path))
  assert res.returncode == 0, res.stderr[-2000:]
  metrics = json.loads((tmp_path / "runs" / "default_diffuse" / "metrics.json").read_text())
  assert metrics["steps"] == 2


@pytest.mark.slow  # render.py in a process
def test_render_without_checkpoint_is_one_clear_line(tmp_path):
  workdir = tmp_path / "empty"
  workdir.mkdir()
  (workdir / "config.json").write_text(config_lib.load("debug").to_json())
  res = _run(["render.py", f"--workdir={workdir}"], ROOT)
  assert res.returncode == 1
  lines = res.stderr.strip().splitlines()
  assert len(lines) == 1 and "no checkpoint" in lines[0], res.stderr


def test_targets_are_recomposited_on_the_configured_background():
  config = small_config()
  config.data.scene = "white"
  config.data.background = "black"
  exp = experiment.setup(config)
  train_ds = exp.train_ds
  empty = train_ds.accs == 0
  assert empty.any() and np.all(train_ds.images[empty] == 1.0)
  rgb = np.asarray(builders.make_train_data(exp).rgb).reshape(train_ds.images.shape)
  assert np.all(rgb[empty] == 0.0)
  opaque = train_ds.accs == 1
  np.testing.assert_allclose(rgb[opaque], train_ds.images[opaque], atol=1e-6)


def test_random_background_old_spelling_trains_as_black_with_the_switch(tmp_path, capsys):
  """data.background='random' (the old spelling) is read as data.background='black' +
  train.random_background=True, with one deprecation line, and the run saves the new
  spelling."""
  config = small_config({"train.max_steps": 3, "data.background": "random"})
  result = train_lib.train_and_evaluate(config, str(tmp_path / "random"))
  assert np.isfinite(result["psnr"])
  notes = [l for l in capsys.readouterr().out.splitlines() if "deprecated" in l]
  assert len(notes) == 1 and "data.background='random'" in notes[0], notes
  assert "train.random_background=True" in notes[0]
  saved = config_lib.load_saved(str(tmp_path / "random"))
  new = small_config({"train.max_steps": 3, "data.background": "black",
                      "train.random_background": True})
  assert saved.data.background == "black" and saved.train.random_background
  assert config_lib.upgrade(config).to_dict() == new.to_dict()


def test_random_background_does_nothing_on_data_without_opacity():
  """On data without opacity the switch is off (no error): a step's loss equals the fixed
  background's."""
  assert background.trains_on_random(True, True)
  assert not background.trains_on_random(True, False)
  assert not background.trains_on_random(False, True)
  losses = {}
  for switch in (False, True):
    exp = experiment.setup(small_config({"train.random_background": switch}))
    exp.train_ds.accs = None
    step = builders.make_train_step(exp)
    _, stats = step(init_state(exp), builders.make_train_data(exp),
                    jax.random.PRNGKey(0))
    losses[switch] = float(stats["loss"])
  assert np.isfinite(losses[True]) and losses[True] == losses[False]


def test_forward_facing_video_follows_a_spiral():
  config = small_config()
  config.data.scene, config.data.ndc = "forward", True
  train_ds = experiment.setup(config).train_ds
  rc = config.render
  poses = camera_paths.video_poses(train_ds, rc.video_frames, config.data.ndc, rc.orbit_phi,
                                   rc.orbit_radius)
  assert poses.shape == (config.render.video_frames, 4, 4)
  # Cameras stay near the capture plane and keep looking down -z, as the training cameras do.
  assert np.all(poses[:, 2, 2] > 0.9)
  spread = np.abs(poses[:, :3, 3] - train_ds.poses[:, :3, 3].mean(0)).max()
  assert spread < 2 * np.abs(train_ds.poses[:, :3, 3]).max() + 1e-3


def test_views_render_at_a_scaled_resolution_with_the_same_field_of_view(trained_run, tmp_path):
  workdir = str(trained_run[0])  # conftest's shared run, read only: the views go to tmp_path
  exp, _ = experiment.restore(workdir)
  train_ds = exp.train_ds
  height, width, (fx, fy, cx, cy) = exp.camera(2.0)
  assert (height, width) == (2 * train_ds.height, 2 * train_ds.width)
  assert (fx / width, cx / width) == pytest.approx((train_ds.intrinsics[0] / train_ds.width,
                                                   train_ds.intrinsics[2] / train_ds.width))
  poses = tmp_path / "poses.npy"
  np.save(poses, train_ds.poses[:2])
  outputs.render(workdir, "views", str(poses), str(tmp_path / "views"), scale=2.0)
  image = imageio.imread(tmp_path / "views" / "view_001.png")
  assert image.shape[:2] == (height, width)
  with pytest.raises(ValueError, match="--scale"):
    outputs.render(workdir, "views", str(poses), scale=0.0)


def test_evaluation_scores_against_truth_on_the_configured_background():
  """A black-background scene trained on white is scored against its images on white."""
  config = small_config()
  config.data.background = "white"
  exp = experiment.setup(config)
  test_ds = exp.test_ds
  variables = init_state(exp).variables
  seen = []
  builders.make_evaluator(exp)(
      variables, max_views=1, on_view=lambda i, out, truth: seen.append(truth))
  empty = test_ds.accs[0] == 0
  assert empty.any() and np.all(seen[0][empty] == 1.0)
  np.testing.assert_allclose(seen[0][~empty], background.images_on_background(
      test_ds, background.parse(config.data.background))[1][0][~empty])


@pytest.mark.parametrize("batching,ndc", [("rays", False), ("images", False), ("rays", True)])
def test_rays_made_per_step_equal_every_pixels_stored_ray(batching, ndc):
  """make_train_data stores no rays; the rays a step draws are the stored-rays path's (every
  pixel's Experiment.rays, stacked) for the same pixels."""
  config = small_config()
  config.train.batching = batching
  if ndc:
    config.data.scene, config.data.ndc = "forward", True
  exp = experiment.setup(config)
  data = builders.make_train_data(exp)
  assert data.rays is None and data.poses.shape == (len(exp.train_ds), 4, 4)
  per_image = [exp.rays(pose).reshape(-1) for pose in exp.train_ds.poses]
  stored = data.replace(rays=jax.tree_util.tree_map(lambda *a: jnp.stack(a), *per_image))
  key = jax.random.PRNGKey(5)
  made, reference = (train_batches.draw_batch(d, builders.batch_settings(config), key) for d in (data, stored))
  np.testing.assert_array_equal(made.rgb, reference.rgb)
  for field in ("origins", "directions", "viewdirs", "near", "far"):
    np.testing.assert_allclose(getattr(made.rays, field), getattr(reference.rays, field),
                               rtol=1e-6, atol=1e-6, err_msg=field)
