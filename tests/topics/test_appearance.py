"""Appearance codes: they condition colour only, held-out views take the mean code, they are off
by default, and on a capture with known per-photo gains they absorb those gains."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.evaluate import evaluation, metrics
from nerf_jax.run import builders, experiment
from nerf_jax.run.signature import init_state, model_signature
from nerf_jax.run import train_lib
from nerf_jax.data import loaders
from nerf_jax.data.scenes import photos
from tests.helpers import restored_variables
from tests.helpers import TINY_GRID, jitted, load_data, small_config


def _field_and_params(base, dims, num_images=5):
  # On the fast base, the tiny grid: the head is what is tested.
  config = small_config(TINY_GRID if base == "fast" else {}, base=base,
                        **{"model.appearance_dims": dims})
  field = builders.make_field(config, num_images)
  return field, jitted(field.init)(jax.random.PRNGKey(0))


@pytest.mark.parametrize("base", ["debug", "fast"])
def test_codes_change_colour_not_density_and_held_out_views_take_the_mean(base):
  field, params = _field_and_params(base, 3)
  table = jax.random.normal(jax.random.PRNGKey(1), params["appearance"].shape)
  params = {**params, "appearance": table}
  points = jax.random.uniform(jax.random.PRNGKey(2), (4, 6, 3), minval=-1.0, maxval=1.0)
  dirs = jnp.tile(jnp.array([0.0, 0.0, -1.0]), (4, 1))
  image = jnp.array([0, 1, 2, 4])
  query = jitted(field.query)
  rgb, sigma = query(params, points, dirs, image=image)
  rgb0, sigma0 = query(params, points, dirs, image=jnp.zeros(4, jnp.int32))
  np.testing.assert_array_equal(sigma, sigma0)  # density never sees the code
  assert np.all(np.abs(np.asarray(rgb - rgb0))[1:].max(axis=(1, 2)) > 1e-4)  # colour does
  # image None: the mean code, i.e. the same as an image whose code is the table's mean.
  with_mean = {**params, "appearance": table.at[4].set(jnp.mean(table, axis=0))}
  mean_rgb, _ = query(params, points, dirs)
  expected, _ = query(with_mean, points, dirs, image=jnp.full(4, 4))
  np.testing.assert_allclose(mean_rgb, expected, atol=1e-6)


def test_off_by_default_leaves_the_network_as_it_was():
  field, params = _field_and_params("debug", 0)
  assert "appearance" not in params and not field.uses_images
  assert set(params) == {f"layer_{i}" for i in range(3)} | {"output"}  # the reference's head
  points = jnp.ones((2, 4, 3)) * 0.3
  dirs = jnp.tile(jnp.array([0.0, 0.0, -1.0]), (2, 1))
  plain = field.query(params, points, dirs)
  ignored = field.query_in_chunks(params, points, dirs, image=jnp.array([0, 1]))
  for a, b in zip(plain, ignored):
    np.testing.assert_array_equal(a, b)
  assert "appearance_dims" not in model_signature(small_config())


def test_the_exposure_capture_has_the_stated_gains_on_training_views_only():
  data = {"scene": "exposure", "num_views": 10, "image_size": 16, "holdout_from": 8}
  train, test = load_data(data)
  plain_train, plain_test = load_data({**data, "scene": "diffuse"})
  gains = photos.gains(8)
  np.testing.assert_array_equal(test.images, plain_test.images)
  np.testing.assert_allclose(train.images, np.clip(plain_train.images * gains[:, None, None],
                                                   0, 1), atol=1e-6)
  assert np.ptp(np.log2(gains.mean(axis=1))) > 0.5  # exposures differ by over half a stop
  _, own_test = load_data({**data, "held_out_looks": "own"})
  own_gains = photos.gains(10)[8:]  # drawn after the training photos' from the same stream
  np.testing.assert_allclose(own_test.images, np.clip(plain_test.images * own_gains[:, None, None],
                                                      0, 1), atol=1e-6)
  _, diffuse_test = load_data({**data, "scene": "diffuse", "held_out_looks": "own"})
  np.testing.assert_array_equal(diffuse_test.images, plain_test.images)  # no looks to give
  with pytest.raises(loaders.DataError, match="held_out_looks='mine'"):
    load_data({**data, "held_out_looks": "mine"})


@pytest.mark.parametrize("dims", [0, 2])
def test_left_half_scores_the_right_half_and_says_so(dims):
  """Under eval.appearance='left_half' the scores are over the right halves, with a code fitted
  on each left half (dims 2) or with no code to fit (dims 0), so the two compare; metrics.json's
  'appearance' says which."""
  config = small_config({"data.scene": "exposure", "data.num_views": 6, "data.holdout_from": 4,
                         "data.image_size": 16, "eval.appearance": "left_half",
                         "eval.fit_steps": 5, "model.appearance_dims": dims})
  exp = experiment.setup(config)
  variables = {"params": init_state(exp).params}
  rendered = {}
  result = builders.make_evaluator(exp)(variables, on_view=lambda i, out, truth: rendered.update(
      {i: (out["rgb"], truth)}))
  assert result["appearance"] == (evaluation.APPEARANCE_PROTOCOLS["left_half"] if dims else
                                  evaluation.NO_CODE_HALF)
  for view in result["per_view"]:
    rgb, truth = rendered[view["view"]]
    assert view["psnr"] == pytest.approx(float(metrics.psnr(rgb[:, 8:], truth[:, 8:])), abs=1e-4)
    assert view["psnr"] != pytest.approx(float(metrics.psnr(rgb, truth)), abs=1e-4)


def _train_view_scores(workdir, config):
  """(PSNR over the training views rendered with their own codes, per view the brightness
  rendered with its code over that with the mean code): the codes' effect, measured on what
  they were fitted to."""
  exp = experiment.setup(config)
  variables = restored_variables(workdir)
  ds = exp.train_ds
  psnrs, brightness = [], []
  render = jitted(exp.renderer.render, background=jnp.zeros(3))
  for i in range(len(ds)):
    rays = exp.rays(ds.poses[i]).reshape(-1)
    image = jnp.full(rays.shape, i) if exp.renderer.field.uses_images else None
    out = render(variables, rays.replace(image=image))
    rgb = np.asarray(out["coarse"]["rgb"]).reshape(ds.images[i].shape)
    psnrs.append(float(metrics.psnr(rgb, ds.images[i])))
    mean_code = render(variables, rays)["coarse"]["rgb"]
    brightness.append(float(rgb.mean() / np.mean(mean_code)))
  return float(np.mean(psnrs)), np.array(brightness)


@pytest.mark.slow
def test_codes_absorb_known_per_photo_gains(tmp_path, monkeypatch):
  """The exposure capture at 16 px with exposures spread over ±1.2 stops, a small grid model,
  150 steps: with codes the training views are explained better, and the brightness each code
  renders follows that photo's gain. Then eval.appearance='left_half' (a code fitted
  on each test image's left half, scores over the right half): with the held-out views
  brightened 1.5x (a gain no training code has) the fitted code scores better on the right half
  than the mean code it starts from."""
  monkeypatch.setattr(photos, "EXPOSURE_STOPS", 1.2)  # a gain the short run cannot miss
  runs = {}
  for dims in (0, 4):
    config = small_config({
        "data.scene": "exposure", "data.num_views": 10, "data.holdout_from": 8,
        "data.image_size": 16, "num_samples": 32, "model.grid.resolutions": (8, 16),
        "model.appearance_dims": dims, "train.appearance_lr": 1e-2,  # 150 steps: fast codes
        "train.max_steps": 150, "train.log_every": 150,
        "train.checkpoint_every": 150, "train.batch_rays": 512}, base="fast")
    workdir = str(tmp_path / f"dims{dims}")
    result = train_lib.train_and_evaluate(config, workdir)
    runs[dims] = _train_view_scores(workdir, config)
  assert result["appearance"].startswith("mean code")
  (psnr_off, _), (psnr_on, brightness) = runs[0], runs[4]
  assert psnr_on > psnr_off + 0.5, (psnr_on, psnr_off)
  gains = photos.gains(8).mean(axis=1)
  rank = lambda a: np.argsort(np.argsort(a))
  corr = np.corrcoef(rank(brightness), rank(gains))[0, 1]  # Spearman's: clipping bends it
  assert corr > 0.8, (corr, brightness, gains)

  config.eval.appearance = "left_half"
  config.eval.fit_steps = 100  # a tenth of the protocol's fit (its step size constant so far)
  exp = experiment.setup(config)
  exp.test_ds.images[:] = np.clip(1.5 * exp.test_ds.images, 0, 1)
  variables = restored_variables(workdir)
  fitted = builders.make_evaluator(exp)(variables)
  exp.config.eval.fit_steps = 0  # the code stays the mean: the same half
  unfitted = builders.make_evaluator(exp)(variables)
  assert fitted["appearance"].startswith("left half")
  assert fitted["psnr"] > unfitted["psnr"] + 0.5, (fitted["psnr"], unfitted["psnr"])
  config.eval.appearance = "whole"
  with pytest.raises(ValueError, match="eval.appearance='whole'"):
    builders.make_evaluator(experiment.setup(config))
