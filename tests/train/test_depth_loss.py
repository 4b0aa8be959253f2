"""The depth term of the sparse points' tracks (nerf_jax/train/losses/depth.py, DS-NeRF): its
'kl' and 'robust' forms and their gradients against a loop written out here over hand-made
densities, its settings' one-line errors, and one train step with it on a COLMAP folder with
tracks (tests/data/test_tracks.py's): the keypoint rays pass through their points after every
move of the world the run makes, and the step adds exactly the term to the loss of the same
batch."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from nerf_jax.data import llff
from nerf_jax.render import compositing
from nerf_jax.run import builders, experiment
from nerf_jax.train import losses, train_batches, train_step
from nerf_jax.train.losses import depth
from nerf_jax.train.state import TrainState
from tests.data.test_tracks import tracked_scene
from tests.helpers import TINY_GRID, requires_pycolmap, small_config

# Three rays of five intervals: a wall at the point, fog in front of it, and an empty ray.
DENSITY = np.array([[0.1, 0.3, 6.0, 2.0, 0.2],
                    [1.5, 1.0, 0.5, 3.0, 0.1],
                    [0.01, 0.02, 0.0, 0.01, 0.03]], np.float32)
EDGES = np.array([[2.0, 2.4, 2.9, 3.1, 3.6, 4.0],
                  [1.0, 1.5, 2.0, 2.2, 2.6, 3.5],
                  [2.0, 2.5, 3.0, 3.5, 4.0, 4.5]], np.float32)
TARGET = np.array([3.0, 2.4, 3.2], np.float32)  # the points' t
SCALE = np.array([3.0, 2.4, 3.2], np.float32)  # z-depth: t itself
ERROR = np.array([0.2, 1.0, 2.0], np.float32)  # over the mean error: the first at the floor
SIGMA, FLOOR, WEIGHT = 0.05, 0.5, 0.7


def _reference(density, form, edges=EDGES):
  """The term's loss (before its weight) written out ray by ray, interval by interval: the
  weights from the densities (transmittance times alpha), then DS-NeRF's KL sum or Charbonnier
  on the expected depth, averaged over the rays."""
  total = 0.0
  for r in range(len(TARGET)):
    spread = SIGMA * max(float(ERROR[r]), FLOOR) * float(SCALE[r])
    transmittance, weights, mids, lengths = 1.0, [], [], []
    for k in range(density.shape[1]):
      length = float(edges[r, k + 1] - edges[r, k])
      alpha = 1.0 - jnp.exp(-density[r, k] * length)
      weights.append(transmittance * alpha)
      transmittance = transmittance * (1.0 - alpha)
      mids.append(0.5 * float(edges[r, k] + edges[r, k + 1]))
      lengths.append(length)
    if form == "kl":
      loss = 0.0
      for w, mid, length in zip(weights, mids, lengths):
        near = np.exp(-(mid - float(TARGET[r])) ** 2 / (2.0 * spread ** 2))
        loss = loss - jnp.log(w + 1e-5) * near * length
    else:
      expected = sum(w * m for w, m in zip(weights, mids)) / sum(weights)
      loss = jnp.sqrt(1.0 + ((expected - float(TARGET[r])) / spread) ** 2) - 1.0
    total = total + loss
  return total / len(TARGET)


def _keypoints():
  count = len(TARGET)
  return train_batches.Keypoints(image=jnp.zeros(count, jnp.int32),
                                 at=jnp.zeros((count, 2), jnp.float32), t=jnp.asarray(TARGET),
                                 scale=jnp.asarray(SCALE), error=jnp.asarray(ERROR))


def _pass(density, edges=EDGES):
  """A render pass's outputs of the densities (compositing.composite, as the renderer's)."""
  out = compositing.composite(jnp.zeros(density.shape + (3,)), density, jnp.asarray(edges))
  return {**out, "t": jnp.asarray(edges)}


def _term(form):
  return depth.build(depth.Settings(weight=WEIGHT, form=form, rays=3, sigma=SIGMA,
                                    min_error_ratio=FLOOR), None)


def _apply(term, outputs):
  inputs = losses.LossInputs(outputs=None, target=None, rays=None, params=None,
                             keypoint_outputs=outputs, keypoints=_keypoints())
  return term(inputs)


@pytest.mark.parametrize("form", ["kl", "robust"])
def test_the_loss_and_its_gradient_match_a_loop_over_the_samples(form):
  term = _term(form)
  loss_of = lambda d: _apply(term, {"coarse": _pass(d)})[0]
  loss, stats = _apply(term, {"coarse": _pass(jnp.asarray(DENSITY))})
  want = _reference(jnp.asarray(DENSITY), form)
  np.testing.assert_allclose(loss, WEIGHT * want, rtol=1e-5)
  np.testing.assert_allclose(stats[form], want, rtol=1e-5)
  got = jax.jit(jax.grad(loss_of))(jnp.asarray(DENSITY))
  expected = jax.jit(jax.grad(lambda d: WEIGHT * _reference(d, form)))(jnp.asarray(DENSITY))
  assert np.all(np.isfinite(got)) and np.abs(got).max() > 0
  np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-6 * np.abs(expected).max())
  # The error stat: |E[t] - D| over the depth (scale), averaged (the empty ray's depth is t_S).
  out = _pass(jnp.asarray(DENSITY))
  np.testing.assert_allclose(stats["error"],
                             np.mean(np.abs(np.asarray(out["depth"]) - TARGET) / SCALE), rtol=1e-5)


def test_kl_pulls_weight_to_the_point_and_away_from_the_fog_in_front():
  grad = jax.grad(lambda d: _apply(_term("kl"), {"coarse": _pass(d)})[0])(jnp.asarray(DENSITY))
  # Ray 1: its point at t = 2.4 (interval 3); the fog of intervals 0 to 2 hides it: less fog,
  # more density where the point is.
  assert np.all(grad[1, :3] > 0) and grad[1, 3] < 0


def test_each_pass_counts_and_the_stats_are_the_final_passs():
  term = _term("kl")
  fine_density = jnp.asarray(DENSITY[::-1].copy())
  loss, stats = _apply(term, {"coarse": _pass(jnp.asarray(DENSITY)), "fine": _pass(fine_density)})
  np.testing.assert_allclose(loss, WEIGHT * (_reference(jnp.asarray(DENSITY), "kl")
                                             + _reference(fine_density, "kl")), rtol=1e-5)
  np.testing.assert_allclose(stats["kl"], _reference(fine_density, "kl"), rtol=1e-5)


def test_rays_a_sample_budget_left_incomplete_are_left_out():
  term = _term("robust")
  out = _pass(jnp.asarray(DENSITY))
  per_ray = [float(np.sqrt(1.0 + ((out["depth"][k] - TARGET[k]) /
                                  (SIGMA * max(ERROR[k], FLOOR) * SCALE[k])) ** 2) - 1.0)
             for k in range(3)]
  np.testing.assert_allclose(_apply(term, {"coarse": out})[0], WEIGHT * np.mean(per_ray),
                             rtol=1e-5)
  loss, _ = _apply(term, {"coarse": {**out, "complete": jnp.array([True, True, False])}})
  np.testing.assert_allclose(loss, WEIGHT * np.mean(per_ray[:2]), rtol=1e-5)


@pytest.mark.parametrize("field,value,match", [
    ("weight", -1.0, "config.loss.depth.weight=-1.0"),
    ("form", "l2", "config.loss.depth.form='l2'"),
    ("rays", 0, "config.loss.depth.rays=0"),
    ("sigma", 0.0, "config.loss.depth.sigma=0.0"),
    ("min_error_ratio", 0.0, "config.loss.depth.min_error_ratio=0.0")])
def test_settings_name_the_field_at_fault(field, value, match):
  with pytest.raises(ValueError, match=match.replace(".", r"\.").replace("(", r"\(")):
    depth.Settings(**{field: value})


def test_off_builds_nothing_and_asks_for_no_keypoint_rays():
  assert depth.build(depth.Settings(), None) is None
  assert losses.keypoint_rays([]) == 0
  assert losses.keypoint_rays([_term("kl")]) == 3
  assert "depth" in losses.Settings().terms and depth.Settings().weight == 0.0


def test_on_without_tracks_is_one_line_naming_the_weight():
  config = small_config(TINY_GRID, base="fast", **{"loss.depth.weight": 0.1})
  exp = experiment.setup(config)  # the built-in scene: no sparse points
  with pytest.raises(ValueError, match=r"config\.loss\.depth\.weight=0\.1 needs the sparse "
                                       r"points' tracks") as info:
    builders.make_train_data(exp)
  assert "\n" not in str(info.value)


def _fresh_state(params, tx):
  params = jax.tree_util.tree_map(jnp.array, params)
  return TrainState(step=jnp.int32(0), params=params, opt_state=tx.init(params),
                    bad_step=jnp.int32(-1), buffers={}, ema={})


@requires_pycolmap
def test_a_train_step_with_the_term_on_a_colmap_folder(tmp_path):
  truth, _, _, model = tracked_scene()
  folder = str(tmp_path / "scene")
  llff.export_llff(truth, folder)
  os.remove(os.path.join(folder, "poses_bounds.npy"))
  os.makedirs(os.path.join(folder, "sparse", "0"))
  model.write(os.path.join(folder, "sparse", "0"))
  fields = {"data.path": folder, "data.focus": True, "model.appearance_dims": 4,
            "train.random_background": False, "train.batch_rays": 64, "num_samples": 8,
            "train.remat_chunk": 0}
  config = small_config(TINY_GRID, base="fast", **fields, **{"loss.depth.weight": 0.1,
                                                             "loss.depth.rays": 16})
  exp = experiment.setup(config)
  data = builders.make_train_data(exp)
  kp = data.keypoints
  assert kp is not None and len(kp) > 100
  # After the loader's and the run's moves of the world (data.focus), each keypoint's ray
  # still passes through its point at its t.
  rays = train_batches.keypoint_rays(data, kp)
  hit = np.asarray(rays.origins) + np.asarray(kp.t)[:, None] * np.asarray(rays.directions)
  gap = np.linalg.norm(hit[:, None] - exp.train_ds.points[None], axis=-1).min(1)
  assert gap.max() < 1e-4 * np.abs(exp.train_ds.points).max()
  ray_renderer = builders.training_renderer(exp)
  terms = builders.loss_terms(config, ray_renderer)
  assert [t.name for t in terms][-1] == "depth"
  settings = builders.step_settings(exp)
  params = ray_renderer.init(jax.random.PRNGKey(0))["params"]
  tx = optax.sgd(0.1)
  run_key = jax.random.PRNGKey(3)
  step = train_step.make_train_step(ray_renderer, tx, terms, settings)
  state, stats = step(_fresh_state(params, tx), data, run_key)
  assert {"depth/kl", "depth/error"} <= set(stats)
  assert all(np.isfinite(float(v)) for v in stats.values())
  assert float(stats["depth/kl"]) > 0 and int(state.bad_step) == -1
  # The same step without the term: the same batch, rendered alike (the keypoints draw from a
  # key of their own), so the losses differ by the term alone (one pass: 0.1 x its KL).
  plain = train_step.make_train_step(ray_renderer, tx, terms[:-1], settings)
  _, plain_stats = plain(_fresh_state(params, tx), data, run_key)
  assert "depth/kl" not in plain_stats
  np.testing.assert_allclose(float(stats["loss"]) - float(plain_stats["loss"]),
                             0.1 * float(stats["depth/kl"]), rtol=1e-4)
