"""Camera pose refinement: the se(3) exponential against the matrix exponential, the similarity
fit, the simulated pose error, and training that recovers a known perturbation."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from nerf_jax.cameras import pose_refinement
from nerf_jax.fields.encodings import posenc
from nerf_jax.fields.encodings import hash as hashgrid
from nerf_jax.run import builders, experiment
from nerf_jax.run.signature import init_state, model_signature
from nerf_jax.train.state import TrainState
from nerf_jax.train import train_step
from nerf_jax.cameras.rays import Rays
from nerf_jax.data.scenes import photos
from tests.helpers import TINY_GRID, jitted, ray_renderer, small_config


def _twist_matrix(xi):
  """The 4x4 matrix of se(3) whose matrix exponential is the rigid transform (brute force)."""
  w, v = np.asarray(xi[:3], np.float64), np.asarray(xi[3:], np.float64)
  m = np.zeros((4, 4))
  m[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
  m[:3, 3] = v
  return m


@pytest.mark.parametrize("angle", [0.0, 1e-4, 0.05, 0.099, 0.101, 0.7, 3.0])
def test_exp_map_matches_the_matrix_exponential(angle):
  rng = np.random.default_rng(int(angle * 1000))
  axis = rng.normal(size=3)
  xi = np.concatenate([angle * axis / np.linalg.norm(axis), rng.normal(size=3)])
  got = np.asarray(pose_refinement.se3_exp(jnp.asarray(xi, jnp.float32)))
  np.testing.assert_allclose(got, scipy.linalg.expm(_twist_matrix(xi)), atol=2e-6)


def test_exp_map_batches_and_is_exactly_the_identity_at_zero():
  out = np.asarray(pose_refinement.se3_exp(jnp.zeros((2, 5, 6))))
  assert out.shape == (2, 5, 4, 4) and np.array_equal(out, np.broadcast_to(np.eye(4), out.shape))
  pose = np.asarray(photos.perturbed(np.eye(4)[None], seed=3))
  # A zero correction leaves a camera bit for bit as given (off = unchanged rays).
  assert np.array_equal(np.asarray(pose_refinement.corrected(pose, jnp.zeros((1, 6)))), pose)


@pytest.mark.parametrize("angle", [0.0, 0.05, 0.7])
def test_exp_map_gradient_matches_finite_differences(angle):
  xi = np.array([0.3, -0.5, 0.8, 0.2, -0.1, 0.4]) * angle / np.linalg.norm([0.3, -0.5, 0.8])
  xi[3:] = [0.2, -0.1, 0.4]
  jac = np.asarray(jax.jacfwd(pose_refinement.se3_exp)(jnp.asarray(xi, jnp.float32)))
  assert np.all(np.isfinite(jac))
  eps = 1e-5
  for k in range(6):
    step = np.eye(6)[k] * eps
    numeric = (scipy.linalg.expm(_twist_matrix(xi + step))
               - scipy.linalg.expm(_twist_matrix(xi - step))) / (2 * eps)
    np.testing.assert_allclose(jac[..., k], numeric, atol=2e-5)


def test_align_recovers_a_known_similarity():
  rng = np.random.default_rng(0)
  src = rng.normal(size=(10, 3))
  rot = photos.rotation(np.array([0.3, -1.1, 0.4]))
  dst = 1.7 * src @ rot.T + np.array([0.5, -2.0, 1.0])
  scale, got_rot, trans = pose_refinement.align(src, dst)
  assert scale == pytest.approx(1.7, abs=1e-12)
  np.testing.assert_allclose(got_rot, rot, atol=1e-12)
  np.testing.assert_allclose(trans, [0.5, -2.0, 1.0], atol=1e-12)
  poses = np.tile(np.eye(4), (10, 1, 1))
  poses[:, :3, 3] = src
  moved = pose_refinement.transform(poses, (scale, got_rot, trans))
  np.testing.assert_allclose(moved[:, :3, 3], dst, atol=1e-5)
  np.testing.assert_allclose(moved[:, :3, :3], np.broadcast_to(rot, (10, 3, 3)), atol=1e-6)


def test_the_simulated_pose_error_is_the_stated_amount():
  poses = np.stack([photos.rotation(np.array([0.1 * k, 0.5, -0.2])) for k in range(8)])
  c2w = np.tile(np.eye(4), (8, 1, 1))
  c2w[:, :3, :3], c2w[:, :3, 3] = poses, np.arange(24).reshape(8, 3)
  noisy = photos.perturbed(c2w, degrees=1.0, translation=0.048, seed=1)
  np.testing.assert_allclose(pose_refinement.rotation_degrees(c2w[:, :3, :3], noisy[:, :3, :3]),
                             1.0, atol=2e-3)  # float32 poses
  np.testing.assert_allclose(np.linalg.norm(noisy[:, :3, 3] - c2w[:, :3, 3], axis=1), 0.048,
                             atol=1e-5)
  assert pose_refinement.pose_errors(c2w, c2w)["degrees"] < 1e-3


def test_coarse_to_fine_weights_open_band_by_band():
  w = lambda a: np.asarray(posenc.coarse_to_fine_weights(jnp.float32(a), 4))
  np.testing.assert_array_equal(w(0.0), [0, 0, 0, 0])
  np.testing.assert_allclose(w(1.5), [1, 0.5, 0, 0], atol=1e-7)
  np.testing.assert_array_equal(w(4.0), [1, 1, 1, 1])  # all open: the plain encoding


THREE_LEVELS = {"grid": {"model.grid.resolutions": (4, 8, 16)},
                "hash": {"model.hash.levels": 3, "model.hash.log2_size": 12,
                         "model.hash.max_resolution": 64}}


@pytest.mark.parametrize("encoding_name", sorted(THREE_LEVELS))
def test_grid_levels_open_coarse_to_fine(encoding_name):
  """BARF's window on a grid network: with no bands open only the coarsest level speaks (the
  same field as with the finer levels' features zeroed by hand, and no gradient reaches them);
  with every band open the field is the plain one."""
  # The tiny grid with three levels (two stages of bands to open).
  config = small_config({**TINY_GRID, "model.encoding": encoding_name,
                         **THREE_LEVELS[encoding_name]}, base="fast")
  field = builders.make_field(config)
  assert field.coarse_to_fine_stages == 2
  params = jitted(field.init)(jax.random.PRNGKey(0))
  points = jax.random.uniform(jax.random.PRNGKey(1), (5, 7, 3), minval=-1.0, maxval=1.0)
  dirs = jnp.zeros((5, 3))
  query = jitted(field.query)
  rgb_all, sigma_all = query(params, points, dirs)
  rgb_open, sigma_open = query(params, points, dirs, bands=jnp.float32(2.0))
  np.testing.assert_array_equal(rgb_open, rgb_all)
  np.testing.assert_array_equal(sigma_open, sigma_all)

  # By hand: the finer levels' parameters zeroed, so their features are zero.
  zeroed = dict(params)
  if encoding_name == "grid":
    zeroed.update({name: jnp.zeros_like(params[name]) for name in ("grid_8", "grid_16")})
  else:
    settings = field.network.encoding.settings
    coarse_rows = hashgrid.level_rows(settings.resolutions, settings.log2_size)[0]
    zeroed["hash_table"] = params["hash_table"].at[coarse_rows:].set(0.0)
  rgb_hand, sigma_hand = query(zeroed, points, dirs)
  rgb_closed, sigma_closed = query(params, points, dirs, bands=jnp.float32(0.0))
  np.testing.assert_allclose(rgb_closed, rgb_hand, atol=1e-6)
  np.testing.assert_allclose(sigma_closed, sigma_hand, atol=1e-6)
  assert not np.allclose(rgb_closed, rgb_all)

  grads = jitted(jax.grad(lambda p: jnp.sum(field.query(p, points, dirs,
                                                        bands=jnp.float32(0.0))[0])))(params)
  if encoding_name == "grid":  # closed levels take no gradient, the open one does
    assert not np.any(np.asarray(grads["grid_8"])) and not np.any(np.asarray(grads["grid_16"]))
    assert np.any(np.asarray(grads["grid_4"]))
  else:
    table = np.asarray(grads["hash_table"])
    assert not np.any(table[coarse_rows:]) and np.any(table[:coarse_rows])


def test_refinement_is_off_by_default_and_leaves_the_state_as_it_was():
  exp = experiment.setup(small_config({"data.scene": "perturbed"}))
  state = init_state(exp)
  assert set(state.params) == {"coarse"}
  assert "pose_refinement" not in model_signature(exp.config)


class _AnalyticField:
  """A stand-in network (tests/helpers.ray_renderer): a textured Gaussian blob, known exactly,
  so pose refinement is tested alone: rgb = sigmoid(sin(4 p + phase)), density 30·exp(-|p|²/0.3)
  (raw density through the config's relu)."""

  coarse_to_fine_stages = 0  # it reads the points alone: no bands to open

  def apply(self, variables, points, dir_features=None):
    rgb = jax.nn.sigmoid(2.0 * jnp.sin(4.0 * points + jnp.array([0.0, 1.0, 2.0])))
    return rgb, 30.0 * jnp.exp(-jnp.sum(points ** 2, axis=-1) / 0.3)


def _train_corrections(exp, start, steps):
  """The cameras' corrections (float32 [N, 6]) after `steps` train steps from `start` (numpy
  [N, 6]; the step donates its state, so the caller's copy stays intact) with exp's stand-in
  network, which has no parameters of its own."""
  params = {"coarse": {}, "poses": jnp.asarray(start, jnp.float32)}
  state = TrainState(step=jnp.array(0, jnp.int32), params=params,
                                opt_state=exp.tx.init(params),
                                bad_step=jnp.array(-1, jnp.int32))
  step = builders.make_train_step(exp)
  data = builders.make_train_data(exp)
  for _ in range(steps):
    state, _ = step(state, data, jax.random.PRNGKey(0))
  return np.asarray(state.params["poses"])


@pytest.mark.parametrize("share", [1.0, 0.5])
def test_refinement_recovers_a_known_perturbation(share):
  """The perturbed capture's cameras (1° and 2% of the scene's size each, photos.py) looking at
  a known field: training steps with the field fixed bring them back to the true poses, also
  when only half of each batch's rays move the poses (train.pose_ray_share)."""
  config = small_config({"data.scene": "perturbed", "data.num_views": 8, "data.holdout_from": 6,
                         "train.pose_ray_share": share,
                         "data.image_size": 16, "num_samples": 32,
                         "train.pose_refinement": True, "train.lr": 1e-2,
                         "train.pose_lr": 1e-2, "train.lr_final": 3e-3, "train.batch_rays": 256,
                         "train.max_steps": 400,
                         # the mechanics alone: the default prior holds part of the correction
                         # back (to 0.68° of 1.10° here; docs/appearance_and_poses.md)
                         "loss.pose_prior.weight": 0.0})
  exp = experiment.setup(config)
  renderer = ray_renderer(config, _AnalyticField())
  ds = exp.train_ds
  render = jitted(renderer.render, background=jnp.zeros(3))
  truth = [render({"params": {"coarse": {}}}, exp.rays(pose).reshape(-1))["coarse"]["rgb"]
           for pose in ds.true_poses]
  ds = dataclasses.replace(ds, images=np.stack([np.asarray(t).reshape(ds.images.shape[1:])
                                                for t in truth]), accs=None)
  exp = dataclasses.replace(exp, renderer=renderer, train_ds=ds)
  corrections = _train_corrections(exp, np.zeros((len(ds), 6)), config.train.max_steps)
  refined = np.asarray(pose_refinement.corrected(ds.poses, corrections))
  given = pose_refinement.pose_errors(ds.poses, ds.true_poses)
  got = pose_refinement.pose_errors(refined, ds.true_poses)
  assert given["degrees"] > 0.8
  assert got["degrees"] < 0.3 * given["degrees"], (got, given)
  assert got["translation"] < 0.3 * given["translation"], (got, given)


def test_a_split_render_is_the_whole_render_with_the_poses_gradient_from_its_head():
  """train_step._render_split against one render of all rays, with a stand-in renderer whose
  output depends on each ray's geometry, background and image: the same values in the same
  order, and the geometry's gradient only on the first `posed` rays."""
  num, posed = 10, 4
  rays = Rays(*(jnp.linspace(0.1, 1.0, num * 3).reshape(num, 3) + k
               for k in range(3)), near=jnp.full((num,), 2.0), far=jnp.full((num,), 6.0))
  background = jnp.linspace(0.0, 1.0, num * 3).reshape(num, 3)
  rays = rays.replace(image=jnp.arange(num, dtype=jnp.int32) % 3)  # rides with the rays

  def render(rays, key, bg):
    del key  # the stand-in is deterministic
    rgb = jnp.sin(rays.origins * rays.directions) + bg + rays.image[:, None]
    return {"coarse": {"rgb": rgb, "t": rays.near[:, None] + jnp.arange(3.0)}}

  whole = render(rays, None, background)
  split = train_step._render_split(render, rays, jax.random.PRNGKey(0), background, posed)
  for name in ("rgb", "t"):
    np.testing.assert_allclose(split["coarse"][name], whole["coarse"][name], rtol=1e-6)
  grad = jax.grad(lambda o: jnp.sum(train_step._render_split(
      render, rays.replace(origins=o), jax.random.PRNGKey(0), background,
      posed)["coarse"]["rgb"]))(rays.origins)
  assert np.all(np.asarray(grad[:posed]) != 0) and not np.any(np.asarray(grad[posed:]))


def test_reprojection_error_of_a_sideways_move_is_focal_times_move_over_depth():
  """A camera facing a plane at depth 4 (every pixel opaque) moved 0.1 sideways sees every
  point shifted by f·0.1/4 pixels; the true camera itself reprojects with no error."""
  f, size, depth, move = 50.0, 20, 4.0, 0.1
  true = np.eye(4)[None]
  moved = true.copy()
  moved[0, 0, 3] = move
  depths, accs = np.full((1, size, size), depth), np.ones((1, size, size))
  surface = (depths, accs, (f, f, size / 2, size / 2))
  assert pose_refinement.reprojection_px(moved, true, *surface) == pytest.approx(f * move / depth)
  assert pose_refinement.reprojection_px(true, true, *surface) == pytest.approx(0.0, abs=1e-12)
  half_transparent = np.where(np.arange(size) < size // 2, 1.0, 0.0)[None, None, :]
  tilted = np.broadcast_to(np.where(np.arange(size) < size // 2, depth, 2 * depth), (1, size,
                                                                                        size))
  # only the opaque half (at depth 4) counts; the far half would shift half as much
  assert pose_refinement.reprojection_px(moved, true, tilted, np.broadcast_to(
      half_transparent, (1, size, size)), (f, f, size / 2, size / 2)) == pytest.approx(
          f * move / depth)


class _EmptyField:
  """A stand-in network with no density anywhere: every ray renders the background, so the
  images say nothing about the poses and only loss.pose_prior.weight acts on the corrections."""

  coarse_to_fine_stages = 0

  def apply(self, variables, points, dir_features=None):
    return jnp.full(points.shape[:-1] + (3,), 0.5), jnp.zeros(points.shape[:-1])


@pytest.mark.parametrize("prior", [0.0, 10.0])
def test_the_pose_prior_pulls_corrections_toward_none_where_images_say_nothing(prior):
  config = small_config({"data.scene": "perturbed", "data.num_views": 6, "data.holdout_from": 4,
                         "data.image_size": 8, "num_samples": 8, "train.pose_refinement": True,
                         "loss.pose_prior.weight": prior, "train.batch_rays": 64,
                         "train.max_steps": 20, "train.warmup_steps": 0})
  exp = experiment.setup(config)
  exp = dataclasses.replace(exp, renderer=ray_renderer(config, _EmptyField()))
  size = jax.random.uniform(jax.random.PRNGKey(1), (len(exp.train_ds), 6), minval=0.01,
                            maxval=0.05)  # far from zero: 5 steps of pose_lr cannot cross it
  start = np.asarray(size * jnp.sign(jax.random.normal(jax.random.PRNGKey(2), size.shape)))
  moved = _train_corrections(exp, start, 5)
  if prior == 0:  # no gradient reaches the corrections: Adam leaves them exactly where they were
    np.testing.assert_array_equal(moved, start)
  else:  # every component moved toward zero (5 Adam steps of at most pose_lr each)
    assert np.all(np.abs(moved) < np.abs(start))
    assert np.all(np.abs(moved - start) <= 5 * config.train.pose_lr * 1.001)
