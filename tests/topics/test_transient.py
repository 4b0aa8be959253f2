"""NeRF-W's transient head (model.transient, loss.transient): the two-part compositing against a
per-ray loop, the loss against its formula, no transient density = today's render bit for bit,
finite gradients at extreme densities, held-out views see the static field alone, off by
default, and a short run with it on trains, checkpoints and restores."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras.rays import Rays
from nerf_jax.render import compositing
from nerf_jax.run import builders, experiment, train_lib
from nerf_jax.run.signature import model_signature
from nerf_jax.train import losses
from nerf_jax.train.losses import colour, transient
from tests.helpers import TINY_GRID, jitted, params_equal, restored_variables, small_config


def _brute_composite(rgb, sigma, rgb_t, sigma_t, beta, t, background, beta_min):
  """NeRF-W eq. 10 ray by ray, sample by sample, in float64."""
  rgb, sigma, rgb_t, sigma_t, beta, t = (np.asarray(a, np.float64)
                                         for a in (rgb, sigma, rgb_t, sigma_t, beta, t))
  num_rays, num_samples = sigma.shape
  out_rgb, out_beta, out_acc = np.zeros((num_rays, 3)), np.zeros(num_rays), np.zeros(num_rays)
  for r in range(num_rays):
    depth_so_far = 0.0  # optical depth of both fields before the sample
    for i in range(num_samples):
      delta = t[r, i + 1] - t[r, i]
      trans = math.exp(-depth_so_far)
      out_rgb[r] += trans * (1 - math.exp(-sigma[r, i] * delta)) * rgb[r, i]
      out_rgb[r] += trans * (1 - math.exp(-sigma_t[r, i] * delta)) * rgb_t[r, i]
      out_beta[r] += trans * (1 - math.exp(-sigma_t[r, i] * delta)) * beta[r, i]
      depth_so_far += (sigma[r, i] + sigma_t[r, i]) * delta
    out_acc[r] = 1 - math.exp(-depth_so_far)
    out_rgb[r] += (1 - out_acc[r]) * np.asarray(background)
  return out_rgb, out_beta + beta_min, out_acc


def _random_samples(num_rays=5, num_samples=7, seed=0):
  keys = jax.random.split(jax.random.PRNGKey(seed), 6)
  rgb = jax.random.uniform(keys[0], (num_rays, num_samples, 3))
  sigma = jax.random.uniform(keys[1], (num_rays, num_samples), maxval=3.0)
  rgb_t = jax.random.uniform(keys[2], (num_rays, num_samples, 3))
  sigma_t = jax.random.uniform(keys[3], (num_rays, num_samples), maxval=2.0)
  beta = jax.random.uniform(keys[4], (num_rays, num_samples), maxval=2.0)
  gaps = jax.random.uniform(keys[5], (num_rays, num_samples + 1), minval=0.05, maxval=0.4)
  t = 2.0 + jnp.cumsum(gaps, axis=-1)
  return rgb, sigma, rgb_t, sigma_t, beta, t


def test_two_part_compositing_matches_a_per_ray_loop():
  rgb, sigma, rgb_t, sigma_t, beta, t = _random_samples()
  background = jnp.array([0.2, 0.5, 0.9])
  out = compositing.composite_with_transient(rgb, sigma, rgb_t, sigma_t, beta, t, background,
                                             beta_min=0.03)
  ref_rgb, ref_beta, ref_acc = _brute_composite(rgb, sigma, rgb_t, sigma_t, beta, t,
                                                background, 0.03)
  np.testing.assert_allclose(out["rgb"], ref_rgb, rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(out["beta"], ref_beta, rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(out["acc"], ref_acc, rtol=1e-5, atol=1e-6)
  # Each field's weights: its own alpha under the transmittance of both.
  total_before = np.concatenate([np.zeros((5, 1)), np.cumsum(
      np.asarray((sigma + sigma_t) * jnp.diff(t), np.float64), axis=-1)[:, :-1]], axis=-1)
  expected_t = np.exp(-total_before) * (1 - np.exp(-np.asarray(sigma_t * jnp.diff(t),
                                                                np.float64)))
  np.testing.assert_allclose(out["transient_weights"], expected_t, rtol=1e-5, atol=1e-7)


def test_no_transient_density_composites_exactly_as_today():
  rgb, sigma, rgb_t, _, beta, t = _random_samples(seed=1)
  background = jnp.array([1.0, 1.0, 1.0])
  today = compositing.composite(rgb, sigma, t, background)
  both = compositing.composite_with_transient(rgb, sigma, rgb_t, jnp.zeros_like(sigma), beta, t,
                                              background, beta_min=0.03)
  for name in ("rgb", "depth", "acc", "weights"):
    np.testing.assert_array_equal(both[name], today[name])
  np.testing.assert_array_equal(both["transient_weights"], 0.0)
  np.testing.assert_allclose(both["beta"], 0.03, rtol=1e-7)


@pytest.mark.parametrize("density", [0.0, 1e-8, 1.0, 1e4, 1e12, 1e30, np.inf])
def test_gradients_stay_finite_for_extreme_densities(density):
  rgb, _, rgb_t, _, beta, t = _random_samples(num_rays=2, num_samples=5, seed=2)
  target = jnp.full((2, 3), 0.5)
  sigma = jnp.full((2, 5), density).at[:, 0].set(0.5)
  sigma_t = jnp.full((2, 5), density).at[:, 1].set(0.0)

  def loss(sigma, sigma_t, rgb, rgb_t, beta):
    out = compositing.composite_with_transient(rgb, sigma, rgb_t, sigma_t, beta, t,
                                               jnp.ones(3), beta_min=0.03)
    density_mean = jnp.minimum(sigma_t, 1e30)  # the head's density is finite (a softplus)
    return jnp.mean(transient.per_ray(out["rgb"], target, out["beta"], density_mean, 0.01))
  value, grads = jax.value_and_grad(loss, argnums=(0, 1, 2, 3, 4))(sigma, sigma_t, rgb, rgb_t,
                                                                   beta)
  assert np.isfinite(value)
  for g in grads:
    assert np.all(np.isfinite(np.asarray(g)))


def test_the_loss_is_nerf_w_equation_13():
  keys = jax.random.split(jax.random.PRNGKey(3), 4)
  rgb = jax.random.uniform(keys[0], (6, 3))
  target = jax.random.uniform(keys[1], (6, 3))
  beta = 0.03 + jax.random.uniform(keys[2], (6,))
  density = jax.random.uniform(keys[3], (6, 4), maxval=5.0)
  outputs = {"coarse": {"rgb": rgb, "beta": beta, "transient_density": density}}
  term = transient.Transient(weight=2.0, density_weight=0.01)
  loss, stats = term(losses.LossInputs(outputs, target, None, {}))
  r, c, b, d = (np.asarray(a, np.float64) for a in (rgb, target, beta, density))
  per_ray = [np.sum((r[i] - c[i]) ** 2) / (2 * b[i] ** 2) + np.log(b[i] ** 2) / 2
             + 0.01 * np.mean(d[i]) for i in range(6)]
  np.testing.assert_allclose(loss, 2.0 * np.mean(per_ray), rtol=1e-5)
  np.testing.assert_allclose(stats["beta"], np.mean(b), rtol=1e-6)
  # Per-ray weights (the data's lossmult): the weighted mean.
  weight = jnp.arange(1.0, 7.0)
  weighted, _ = term(losses.LossInputs(outputs, target, None, {}, weight))
  np.testing.assert_allclose(weighted, 2.0 * np.average(per_ray, weights=np.arange(1, 7)),
                             rtol=1e-5)
  # The colour term leaves that pass to this one: a coarse pass before it keeps its own.
  both = {"coarse": {"rgb": target + 0.1}, "fine": outputs["coarse"]}
  colour_loss, colour_stats = colour.Colour(coarse_weight=0.5)(
      losses.LossInputs(both, target, None, {}))
  np.testing.assert_allclose(colour_loss, 0.5 * 0.01, rtol=1e-5)
  np.testing.assert_allclose(colour_stats["psnr"], -10 * np.log10(np.mean((r - c) ** 2)),
                             rtol=1e-5)
  alone, _ = colour.Colour()(losses.LossInputs(outputs, target, None, {}))
  assert float(alone) == 0.0


def _tiny(dims, **fields):
  return small_config(TINY_GRID, base="fast", **{"model.transient.dims": dims, **fields})


def _rays(num=8):
  origins = jnp.tile(jnp.array([0.0, 0.0, 3.0]), (num, 1))
  xy = jnp.stack([jnp.linspace(-0.3, 0.3, num), jnp.linspace(0.2, -0.2, num)], axis=-1)
  directions = jnp.concatenate([xy, -jnp.ones((num, 1))], axis=-1)
  viewdirs = directions / jnp.linalg.norm(directions, axis=-1, keepdims=True)
  return Rays(origins, directions, viewdirs, jnp.full(num, 2.0), jnp.full(num, 4.5))


def test_an_empty_head_renders_as_today_and_held_out_views_see_the_static_field():
  with_head = builders.make_ray_renderer(_tiny(4), num_images=3)
  today = builders.make_ray_renderer(_tiny(0), num_images=3)
  variables = with_head.init(jax.random.PRNGKey(0))
  static = {**variables, "params": {k: v for k, v in variables["params"].items()
                                    if k != "transient"}}
  assert params_equal(static["params"], today.init(jax.random.PRNGKey(0))["params"])
  rays = _rays()
  bg = jnp.ones(3)
  expected = jitted(today.render)(static, rays, background=bg)["coarse"]
  # Held out (no image): the static field alone, whatever the head holds.
  held_out = jitted(with_head.render)(variables, rays, background=bg)["coarse"]
  assert "beta" not in held_out
  for name in ("rgb", "depth", "acc", "weights"):
    np.testing.assert_array_equal(held_out[name], expected[name])
  # A training ray whose head gives density exactly 0 (softplus(-200) underflows to 0).
  head = variables["params"]["transient"]
  output = {**head["output"], "kernel": head["output"]["kernel"].at[:, 3].set(0.0),
            "bias": head["output"]["bias"].at[3].set(-200.0)}
  empty = {**variables, "params": {**variables["params"], "transient": {**head,
                                                                          "output": output}}}
  trained = jitted(with_head.render)(empty, rays.replace(image=jnp.arange(8) % 3),
                                     background=bg)["coarse"]
  for name in ("rgb", "depth", "acc", "weights"):
    np.testing.assert_array_equal(trained[name], expected[name])
  assert np.all(np.asarray(trained["beta"]) == np.float32(0.03))
  # With the head as initialised, a training ray differs: the head is there.
  seen = jitted(with_head.render)(variables, rays.replace(image=jnp.arange(8) % 3),
                                  background=bg)["coarse"]
  assert np.max(np.abs(np.asarray(seen["rgb"] - expected["rgb"]))) > 1e-4


def test_off_by_default_and_bad_settings_get_one_line():
  config = small_config()
  assert builders.make_ray_renderer(config).transient is None
  assert not any(k.startswith("transient") for k in model_signature(config))
  renderer = builders.make_ray_renderer(config)
  assert all(term.name != "transient" for term in builders.loss_terms(config, renderer))
  on = _tiny(16)
  assert model_signature(on)["transient_dims"] == 16
  terms = builders.loss_terms(on, builders.make_ray_renderer(on))
  assert [term.name for term in terms][-1] == "transient"  # added, though not listed
  with pytest.raises(ValueError, match="colour_fraction"):
    builders.make_ray_renderer(_tiny(16, **{"model.colour_fraction": 0.5}))
  with pytest.raises(ValueError, match="model.transient.beta_min"):
    builders.make_ray_renderer(_tiny(16, **{"model.transient.beta_min": 0.0}))
  with pytest.raises(ValueError, match="loss.transient.weight=0"):
    builders.loss_terms(_tiny(16, **{"loss.transient.weight": 0.0}),
                          builders.make_ray_renderer(on))


def test_a_short_run_with_the_head_trains_checkpoints_and_restores(tmp_path):
  config = _tiny(4, **{"train.max_steps": 6, "train.log_every": 6,
                       "train.checkpoint_every": 6})
  result = train_lib.train_and_evaluate(config, str(tmp_path))
  assert result["steps"] == 6 and np.isfinite(result["psnr"])
  variables = restored_variables(tmp_path)
  exp = experiment.setup(config)
  assert variables["params"]["transient"]["embedding"].shape == (len(exp.train_ds), 4)
  fresh = exp.renderer.init(jax.random.PRNGKey(config.seed))["params"]["transient"]
  assert not np.array_equal(variables["params"]["transient"]["output"]["kernel"],
                            fresh["output"]["kernel"])  # the head was trained
  # The held-out score is the static field's: the evaluator renders without images.
  evaluated = builders.make_evaluator(exp)(variables)
  np.testing.assert_allclose(evaluated["psnr"], result["psnr"], rtol=1e-5)
