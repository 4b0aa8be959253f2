"""Intrinsics refinement (nerf_jax/cameras/intrinsics_refinement.py): a focal scale per training
image and one shared radial lens, against today's rays, a numpy brute force, a fit to known
cameras, and a short training run that checkpoints and restores."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from nerf_jax.cameras import intrinsics_refinement as ir
from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data import lens as lens_lib
from nerf_jax.data.scenes import landmark
from nerf_jax.run import builders, experiment, train_lib
from nerf_jax.run.signature import init_state, model_signature
from nerf_jax.train import train_batches
from tests.helpers import TINY_GRID, restored_variables, small_config

HEIGHT, WIDTH = 12, 20
INTRINSICS = (18.0, 17.0, 9.5, 6.25)  # fx != fy and an off-centre point: swapped axes show
C2W = np.array(rays_lib.pose_spherical(30.0, -20.0, 3.0))


def _pixels():
  """Every pixel's column i and row j, float32 [H, W] each."""
  return jnp.meshgrid(jnp.arange(WIDTH, dtype=jnp.float32),
                      jnp.arange(HEIGHT, dtype=jnp.float32), indexing="xy")


def _rays(lens=None, use_ndc=False, pixel_center=0.5):
  i, j = _pixels()
  near, far = (0.0, 1.0) if use_ndc else (0.5, 6.0)
  make = jax.jit(lambda i, j, lens: rays_lib.pixel_rays(
      i, j, HEIGHT, WIDTH, INTRINSICS, C2W, near, far, pixel_center, use_ndc, True, lens))
  return make(i, j, lens)


def _lens(log_focal, k):
  return ir.Lens(jnp.full((HEIGHT, WIDTH), log_focal, jnp.float32),
                 jnp.broadcast_to(jnp.asarray(k, jnp.float32), (HEIGHT, WIDTH, 2)))


@pytest.mark.parametrize("use_ndc", [False, True])
def test_zeros_are_todays_rays_bit_for_bit(use_ndc):
  today, zeros = _rays(None, use_ndc), _rays(_lens(0.0, (0.0, 0.0)), use_ndc)
  for a, b in zip(jax.tree_util.tree_leaves(today), jax.tree_util.tree_leaves(zeros)):
    assert np.array_equal(np.asarray(a), np.asarray(b))


def _brute_camera_xy(i, j, log_focal, k, pixel_center=0.5):
  """float64 [..., 2]: the refined camera-space (x, y) (z = -1) of pixels (i, j), written out:
  the distorted coordinates through the focal f·exp(s), times 1 + k1 r² + k2 r⁴."""
  fx, fy, cx, cy = INTRINSICS
  xd = (i + pixel_center - cx) / (fx * math.exp(log_focal))
  yd = -(j + pixel_center - cy) / (fy * math.exp(log_focal))
  r2 = xd ** 2 + yd ** 2
  g = 1.0 + k[0] * r2 + k[1] * r2 ** 2
  return np.stack([xd * g, yd * g], -1)


def test_a_focal_scale_and_a_lens_move_each_ray_as_written_out():
  log_focal, k = 0.3, (0.4, 0.1)  # undistorting a barrel lens
  got = _rays(_lens(log_focal, k))
  i, j = [np.asarray(a, np.float64) for a in _pixels()]
  xy = _brute_camera_xy(i, j, log_focal, k)
  cam = np.concatenate([xy, -np.ones_like(xy[..., :1])], -1)
  want = cam @ C2W[:3, :3].astype(np.float64).T
  np.testing.assert_allclose(np.asarray(got.directions), want, rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(np.asarray(got.origins), np.broadcast_to(C2W[:3, 3], want.shape),
                             atol=1e-6)
  # The footprint: the pixel's area in the z = -1 plane (a central difference of the map over
  # one pixel, float64) in a disc of the same variance (rays.PIXEL_TO_RADIUS).
  step = 1e-4
  dxy_di = (_brute_camera_xy(i + step, j, log_focal, k) -
            _brute_camera_xy(i - step, j, log_focal, k)) / (2 * step)
  dxy_dj = (_brute_camera_xy(i, j + step, log_focal, k) -
            _brute_camera_xy(i, j - step, log_focal, k)) / (2 * step)
  area = np.abs(dxy_di[..., 0] * dxy_dj[..., 1] - dxy_di[..., 1] * dxy_dj[..., 0])
  np.testing.assert_allclose(np.asarray(got.radii), rays_lib.PIXEL_TO_RADIUS * np.sqrt(area),
                             rtol=1e-4)


def test_gradients_are_finite_at_zero_and_at_the_principal_point():
  """At zeros, at the principal point (r = 0) too: d x_u / d s = -x, d x_u / d k1 = x r²,
  d x_u / d k2 = x r⁴ (x_u = x_d (1 + k1 r² + k2 r⁴), x_d = x exp(-s))."""
  fx, fy, cx, cy = INTRINSICS
  i = jnp.array([cx - 0.5, 3.0, 17.0], jnp.float32)  # the first pixel's ray is the axis
  j = jnp.array([cy - 0.5, 2.0, 10.0], jnp.float32)

  def directions(params):
    lens = ir.Lens(jnp.broadcast_to(params[0], i.shape), jnp.broadcast_to(params[1:], (3, 2)))
    rays = rays_lib.pixel_rays(i, j, HEIGHT, WIDTH, INTRINSICS, C2W, 0.5, 6.0, 0.5, False, True,
                               lens)
    return rays.directions, rays.radii

  jac = jax.jit(jax.jacfwd(lambda p: directions(p)[0]))(jnp.zeros(3))
  total = lambda p: jnp.sum(directions(p)[0]) + jnp.sum(directions(p)[1])
  grads = jax.jit(jax.grad(total))(jnp.zeros(3))
  assert np.all(np.isfinite(np.asarray(jac))) and np.all(np.isfinite(np.asarray(grads)))
  x = (np.asarray(i) + 0.5 - cx) / fx
  y = -(np.asarray(j) + 0.5 - cy) / fy
  r2 = x * x + y * y
  rot = C2W[:3, :3].astype(np.float64)
  cam = lambda dx, dy: np.stack([dx, dy, np.zeros_like(dx)], -1) @ rot.T
  np.testing.assert_allclose(np.asarray(jac[..., 0]), cam(-x, -y), atol=1e-6)
  np.testing.assert_allclose(np.asarray(jac[..., 1]), cam(x * r2, y * r2), atol=1e-6)
  np.testing.assert_allclose(np.asarray(jac[..., 2]), cam(x * r2 ** 2, y * r2 ** 2), atol=1e-6)


FIT_SIZE, FIT_FOCAL = 16, 22.222  # the landmark scene's stored camera at 16 px: r_d <= 0.88


def _fit(stored, target, steps=3000):
  """params['intrinsics'] from zeros by Adam (decaying 3e-2 -> 3e-4) matching each image's
  refined (x, y) of `stored` (float32 [N, P, 3], the stored camera's directions) to `target`
  (float32 [N, P, 2]) in the stored camera's pixels (squared error); and the rms error left
  (pixels)."""
  num_images = stored.shape[0]
  images = jnp.repeat(jnp.arange(num_images)[:, None], stored.shape[1], 1)

  def loss(params):
    refined = ir.lens_of(params, images).undistort(stored)[0][..., :2]
    return jnp.mean(jnp.sum((FIT_FOCAL * (refined - target)) ** 2, -1))

  tx = optax.adam(optax.exponential_decay(3e-2, steps, 1e-2))
  params = ir.initial(num_images)

  def step(carry, _):
    params, opt = carry
    updates, opt = tx.update(jax.grad(loss)(params), opt)
    return (optax.apply_updates(params, updates), opt), None
  (params, _), _ = jax.jit(lambda c: jax.lax.scan(step, c, None, steps))(
      (params, tx.init(params)))
  return params, float(np.sqrt(loss(params)))


def test_a_fit_recovers_known_focal_scales_and_a_lens():
  """Five photos of the landmark's zooms (focal spread 3x around the stored one: log scales
  -0.55..0.55) at its 16 px camera: from the stored pinhole's directions, gradient descent on
  the rays' error alone. (a) A lens of the model's own family (undistortion (0.3, 0.25)):
  every focal scale within 1e-3, (k1, k2) within 1e-2 (k2 moves rays by r⁴ <= 0.6 of it: the
  slowest direction for the optimiser), the rays within 0.01 px. (b) A landmark photo's
  Brown–Conrady lens (forward k1 = -0.32, landmark.photo_rays' rays: lens.undistort, float64):
  the two-term inverse is not exact, and a common zoom trades against the lens's r² term, so
  the focal scales come within 0.04 (of a spread of 1.1) and the rays within 0.1 px rms (they
  land at 0.02-0.03 and 0.064 px; the pinhole leaves several pixels)."""
  focals, dists = landmark.lenses(5, FIT_FOCAL)
  true_s = np.log(focals / FIT_FOCAL)
  i, j = jnp.meshgrid(jnp.arange(FIT_SIZE, dtype=jnp.float32),
                      jnp.arange(FIT_SIZE, dtype=jnp.float32), indexing="xy")
  centre = FIT_SIZE / 2
  stored = rays_lib.pixel_directions(FIT_SIZE, FIT_SIZE, FIT_FOCAL, FIT_FOCAL, centre, centre,
                                     0.5).reshape(-1, 3)
  stored = jnp.broadcast_to(stored, (5, *stored.shape))
  # (a) the model's own family, in float64
  k_true = np.array([0.3, 0.25])
  xd = np.asarray(stored, np.float64)[..., :2] * np.exp(-true_s)[:, None, None]
  r2 = np.sum(xd ** 2, -1, keepdims=True)
  params, rms = _fit(stored, jnp.asarray(xd * (1 + k_true[0] * r2 + k_true[1] * r2 ** 2),
                                         jnp.float32))
  np.testing.assert_allclose(np.asarray(params["log_focal"]), true_s, atol=1e-3)
  np.testing.assert_allclose(np.asarray(params["k"]), k_true, atol=1e-2)
  assert rms < 0.01, rms
  # (b) Brown–Conrady's forward lens of a landmark photo, as landmark.photo_rays makes its rays
  truth = [landmark.photo_rays(np.eye(4), FIT_SIZE, FIT_SIZE, f, dists[0])[1] for f in focals]
  target = np.stack([d[:, :2] / -d[:, 2:] for d in truth])  # (x, y) at z = -1
  pinhole = float(np.sqrt(np.mean(np.sum((FIT_FOCAL * (target - np.asarray(stored)[..., :2])) ** 2,
                                         -1))))
  params, rms = _fit(stored, jnp.asarray(target, jnp.float32))
  np.testing.assert_allclose(np.asarray(params["log_focal"]), true_s, atol=0.04)
  assert rms < 0.1 < pinhole, (rms, pinhole, np.asarray(params["k"]))


def test_per_image_cameras_refuse_with_the_fields_named():
  data = train_batches.TrainData(rays=None, rgb=jnp.zeros((4, 3)), acc=jnp.zeros(4),
                                 poses=jnp.tile(jnp.eye(4), (2, 1, 1)),
                                 camera=(None, None, None, 0.1, 5.0, 0.5, False),
                                 offsets=jnp.array([0, 2]),
                                 cameras=jnp.ones((2, 6)))
  with pytest.raises(ValueError, match=r"config.train.intrinsics_refinement.*image_cameras"):
    train_batches.pixel_rays_of(data, jnp.array([0, 1]), jnp.array([0, 1]),
                                intrinsics=ir.initial(2))


def _config(overrides=None):
  return small_config({**TINY_GRID, "data.scene": "landmark", "train.max_steps": 10,
                       "train.log_every": 10, "train.checkpoint_every": 10,
                       "train.intrinsics_refinement": True, **(overrides or {})}, base="fast")


@pytest.mark.parametrize("poses", [False, True])
def test_train_steps_move_the_focal_scales_and_the_lens(poses):
  """A few train steps, with and without pose refinement: finite losses, parameters and an
  Adam of their own, and each image's focal scale and the lens take a step."""
  exp = experiment.setup(_config({"train.pose_refinement": poses}))
  state = init_state(exp)
  assert set(state.params["intrinsics"]) == {"log_focal", "k"}
  assert state.params["intrinsics"]["log_focal"].shape == (len(exp.train_ds),)
  assert "intrinsics" in state.opt_state.inner_states
  step, data = builders.make_train_step(exp), builders.make_train_data(exp)
  for _ in range(3):
    state, stats = step(state, data, jax.random.PRNGKey(0))
    assert np.isfinite(float(stats["loss"]))
  assert int(state.bad_step) == -1
  assert np.all(np.asarray(state.params["intrinsics"]["log_focal"]) != 0.0)
  assert np.all(np.asarray(state.params["intrinsics"]["k"]) != 0.0)


def test_off_by_default_and_a_run_checkpoints_and_restores_with_it(tmp_path):
  off = experiment.setup(small_config({"data.scene": "perturbed"}))
  assert "intrinsics" not in init_state(off).params
  assert "intrinsics_refinement" not in model_signature(off.config)
  config = _config()
  metrics = train_lib.train_and_evaluate(config, str(tmp_path))
  assert np.isfinite(metrics["psnr"])
  exp, _ = experiment.restore(str(tmp_path))
  assert model_signature(exp.config)["intrinsics_refinement"] is True
  restored = restored_variables(tmp_path)["params"]["intrinsics"]
  assert restored["log_focal"].shape == (len(exp.train_ds),) and restored["k"].shape == (2,)
  assert np.all(np.isfinite(np.asarray(restored["log_focal"])))
