"""Each effect works, not only runs: what every declared-effects config computes in a train step
(spies on the field queries, the encodings and the compositing), the random background's target,
view dependence and NDC rendering on briefly trained built-in scenes."""

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax import (compositing, encoding, experiment, field, outputs, renderer, scenes,
                      train_lib)
from nerf_jax.rays import Rays
from nerf_jax.scenes import simulator
from tests.conftest import assert_beats_trivial, tiny_config

SCENES = ["diffuse", "glossy", "fog", "white", "forward"]


def _scene_config(name, **data):
  """configs/scenes/<name>.py shrunk to seconds (its effect switches untouched)."""
  config = importlib.import_module(f"nerf_jax.configs.scenes.{name}").get_config()
  config.data.num_views, config.data.image_size, config.data.holdout_from = 6, 16, 5
  config.model.depth, config.model.width, config.model.skip_layers = 2, 16, (0,)
  config.train.batch_rays, config.train.remat_chunk = 32, 0
  config.render.after_training = False
  for k, v in data.items():
    config.data[k] = v
  return config


def _spy_one_step(monkeypatch, config):
  """Run one eager train step of `config`; returns the recorded calls: 'query' (points, params),
  'encode' (input width, frequency bands), 'composite' (t, background)."""
  calls = {"query": [], "encode": [], "composite": []}
  query, encode, composite = field.query, encoding.positional_encoding, compositing.composite

  def spy_query(model, params, points, *args, **kw):
    calls["query"].append((np.asarray(points), params))
    return query(model, params, points, *args, **kw)

  def spy_encode(x, dims):
    calls["encode"].append((x.shape[-1], dims))
    return encode(x, dims)

  def spy_composite(rgb, sigma, t, background=None):
    calls["composite"].append((np.asarray(t), None if background is None else
                               np.asarray(background)))
    return composite(rgb, sigma, t, background)

  monkeypatch.setattr(field, "query", spy_query)
  monkeypatch.setattr(encoding, "positional_encoding", spy_encode)
  monkeypatch.setattr(compositing, "composite", spy_composite)
  exp = experiment.setup(config)
  data = train_lib.make_train_data(exp)
  with jax.disable_jit():  # concrete values reach the spies
    train_lib.make_train_step(exp)(experiment.init_state(exp), data, jax.random.PRNGKey(0))
  return calls


@pytest.mark.parametrize("name", SCENES)
def test_each_scene_configs_switches_change_what_a_step_computes(monkeypatch, name):
  config = _scene_config(name)
  calls = _spy_one_step(monkeypatch, config)
  rays, coarse = config.train.batch_rays, config.num_samples
  fine = config.num_fine_samples
  # Hierarchical sampling: a second query with coarse + fine samples, on the shared network.
  shapes = [points.shape for points, _ in calls["query"]]
  assert shapes == [(rays, coarse, 3)] + ([(rays, coarse + fine, 3)] if fine else []), shapes
  if fine:
    assert calls["query"][1][1] is calls["query"][0][1]  # shared_fine: the coarse parameters
  # View dependence: directions are encoded (3 inputs, dir_encode_dims bands) and reach the model.
  encoded = calls["encode"]
  pos = (3, config.pos_encode_dims)
  dirs = [(3, config.dir_encode_dims)] if config.model.view_dependent else []
  assert encoded == [pos, *dirs] * len(shapes), encoded
  # The background the field is composited on.
  for _, background in calls["composite"]:
    np.testing.assert_array_equal(background, {"white": [1, 1, 1]}.get(name, [0, 0, 0]))
  # NDC: t runs over [0, 1] and the points lie in the NDC cube; otherwise z-depth [2, 6].
  t = calls["composite"][0][0]
  points = calls["query"][0][0]
  if config.data.ndc:
    assert t.min() == 0.0 and t.max() == 1.0
    assert np.all(np.abs(points[..., 2]) <= 1.0 + 1e-5)
  else:
    assert t.min() == 2.0 and t.max() == 6.0
  # A switch set by the scene config, flipped, changes the count (the spies see the change).
  assert config.model.view_dependent == (name == "glossy")
  assert (fine > 0) == (name == "fog") and config.data.ndc == (name == "forward")


def test_flipping_a_switch_changes_the_spied_step(monkeypatch):
  """The same spies on the diffuse config with view dependence and a fine pass switched on."""
  config = _scene_config("diffuse")
  config.model.view_dependent, config.num_fine_samples = True, 8
  calls = _spy_one_step(monkeypatch, config)
  assert [p.shape[1] for p, _ in calls["query"]] == [config.num_samples, config.num_samples + 8]
  assert calls["query"][1][1] is not calls["query"][0][1]  # an unshared fine network
  assert [d for _, d in calls["encode"]] == [config.pos_encode_dims, config.dir_encode_dims] * 2


def _loss(monkeypatch, rendered, acc, pixel=0.3):
  """The train loss of one step with background 'random', every target pixel `pixel` with
  opacity `acc`, and a field whose render is `rendered(background)`."""
  def fake_render(model, params, rays, config, key=None, background=None):
    del model, params, config, key
    rgb = jnp.broadcast_to(rendered(background), (*rays.shape, 3))
    return {"coarse": {"rgb": rgb}}
  monkeypatch.setattr(renderer, "render_rays", fake_render)
  config = tiny_config()
  config.data.background = "random"
  exp = experiment.setup(config)
  data = train_lib.make_train_data(exp)
  data = data.replace(rgb=jnp.full_like(data.rgb, pixel), acc=jnp.full_like(data.acc, acc))
  _, stats = train_lib.make_train_step(exp)(experiment.init_state(exp), data,
                                            jax.random.PRNGKey(0))
  return float(stats["loss"])


def test_random_background_target_is_the_background_where_empty_and_the_pixel_where_opaque(
    monkeypatch):
  transparent = lambda background: background  # renders exactly the background it is given
  black = lambda background: jnp.zeros(3)  # an opaque black object
  # Opacity 0 (the pixel is the data's black background): the target is the per-ray
  # background, the transparent field's render exactly.
  assert _loss(monkeypatch, transparent, acc=0.0, pixel=0.0) == 0.0
  # Opacity 1: the target is the pixel, whatever the background.
  assert _loss(monkeypatch, black, acc=1.0) == pytest.approx(0.09, rel=1e-6)
  # ... and the background is random per ray, uniform in [0, 1]: E[(U - 0.3)^2] = 0.1233.
  assert _loss(monkeypatch, transparent, acc=1.0) == pytest.approx(1 / 3 - 0.3 + 0.09, abs=0.02)
  # Opacity 0 against a black render: E[U^2] = 1/3.
  assert _loss(monkeypatch, black, acc=0.0, pixel=0.0) == pytest.approx(1 / 3, abs=0.03)
