"""Tests of the LLFF format (export, load, conventions) and the spiral render path."""

import math
import os

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data import scenes
from nerf_jax.data import Dataset, export, export_llff, load_llff
from tests.helpers import assert_data_error as _error, load_data

Q = 1.0 / 255 + 1e-6  # 8-bit quantisation


@pytest.fixture(scope="module")
def forward():
  return scenes.make_dataset("forward", num_views=10, height=12, width=16, focal=20.0)


def _rotation(axis, degrees):
  """float64 [3, 3], a right-handed rotation about the unit vector `axis` (Rodrigues)."""
  k = np.asarray(axis, np.float64) / np.linalg.norm(axis)
  cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
  a = math.radians(degrees)
  return np.eye(3) + math.sin(a) * cross + (1 - math.cos(a)) * cross @ cross


def _rigid(rotation, translation):
  out = np.eye(4)
  out[:3, :3], out[:3, 3] = rotation, translation
  return out


def _tiny(poses, near=2.0, far=8.0):
  """A Dataset of 4 x 6 random images with the given poses (float [N, 4, 4])."""
  rng = np.random.default_rng(0)
  images = rng.uniform(size=(len(poses), 4, 6, 3)).astype(np.float32)
  return Dataset(images, np.asarray(poses, np.float32), (5.0, 5.0, 3.0, 2.0), near, far, name="t")


def test_round_trip_of_the_forward_scene(forward, tmp_path):
  export_llff(forward, str(tmp_path))
  back = load_llff(str(tmp_path))
  np.testing.assert_allclose(back.poses, forward.poses, atol=1e-5)
  np.testing.assert_allclose(back.images, forward.images, atol=Q)
  assert back.intrinsics == forward.intrinsics
  assert (back.near, back.far) == (forward.near, forward.far)
  assert back.forward_facing and back.accs is None and back.background == (0.0, 0.0, 0.0)
  assert sorted(os.listdir(tmp_path / "images"))[:2] == ["000.png", "001.png"]


def test_file_uses_llff_axis_order(forward, tmp_path):
  """Identity NeRF rotations ([right, up, backwards] = world x, y, z) are stored as LLFF's
  [down, right, backwards] = [-y, x, z], followed by t, (h, w, f) and the bounds."""
  export_llff(forward, str(tmp_path))
  table = np.load(tmp_path / "poses_bounds.npy")
  assert table.shape == (10, 17)
  matrix = table[3, :15].reshape(3, 5)
  np.testing.assert_array_equal(matrix[:, :3], [[0, 1, 0], [-1, 0, 0], [0, 0, 1]])
  np.testing.assert_array_equal(matrix[:, 3], forward.poses[3, :3, 3])
  np.testing.assert_array_equal(matrix[:, 4], [12, 16, 20.0])
  np.testing.assert_array_equal(table[:, 15:], np.tile([forward.near, forward.far], (10, 1)))


def test_round_trip_of_rotated_cameras(tmp_path):
  poses = [_rigid(_rotation([1, 2, 3], 10.0 * k), [k, -1.0, 0.5 * k]) for k in range(5)]
  export_llff(_tiny(poses), str(tmp_path))
  np.testing.assert_allclose(load_llff(str(tmp_path)).poses, np.stack(poses), atol=1e-6)


def test_bd_factor_rescales_to_a_near_bound_above_one(tmp_path):
  poses = [_rigid(_rotation([0, 1, 0], 5.0 * k), [0.2 * k, 0.1, 3.0]) for k in range(3)]
  export_llff(_tiny(poses, near=2.5, far=9.0), str(tmp_path))
  plain, scaled = load_llff(str(tmp_path)), load_llff(str(tmp_path), bd_factor=0.75)
  scale = 1.0 / (0.75 * 2.5)
  assert scaled.near == pytest.approx(1.0 / 0.75) and scaled.far == pytest.approx(9.0 * scale)
  np.testing.assert_allclose(scaled.poses[:, :3, :3], plain.poses[:, :3, :3])
  np.testing.assert_allclose(scaled.poses[:, :3, 3], plain.poses[:, :3, 3] * scale, rtol=1e-6)
  assert scaled.intrinsics == plain.intrinsics


def test_recenter_removes_the_capture_frame(tmp_path):
  local = scenes.forward_poses(6, seed=2).astype(np.float64)
  local[:, :3, :3] = [_rotation([1, -1, 0.5], 4.0 * k - 10.0) for k in range(6)]  # wobble
  world = _rigid(_rotation([0.3, 1.0, -0.2], 70.0), [2.0, -3.0, 1.0])  # e.g. COLMAP's frame
  export_llff(_tiny(local), str(tmp_path / "local"))
  export_llff(_tiny(world @ local), str(tmp_path / "world"))
  a = load_llff(str(tmp_path / "local"), recenter=True).poses
  b = load_llff(str(tmp_path / "world"), recenter=True).poses
  np.testing.assert_allclose(a, b, atol=1e-5)  # the same capture, whatever its world frame
  np.testing.assert_allclose(b[:, :3, 3].mean(0), 0.0, atol=1e-6)  # the mean centre is the origin
  mean_back = b[:, :3, 2].sum(0)
  np.testing.assert_allclose(mean_back / np.linalg.norm(mean_back), [0, 0, 1], atol=1e-6)
  relative = lambda p: np.linalg.inv(p[0]) @ p[1:]
  np.testing.assert_allclose(relative(b), relative(world @ local), atol=1e-5)  # rigid


def test_factor_downsamples_or_reads_images_n(forward, tmp_path):
  export_llff(forward, str(tmp_path))
  half = load_llff(str(tmp_path), factor=2)  # no images_2/: block average of images/
  assert half.images.shape == (10, 6, 8, 3) and half.focal == pytest.approx(10.0)
  full = load_llff(str(tmp_path))
  np.testing.assert_allclose(half.images[:, 0, 0], full.images[:, :2, :2].mean((1, 2)), atol=1e-6)
  os.makedirs(tmp_path / "images_2")
  for k in range(10):
    iio.imwrite(tmp_path / "images_2" / f"{k:03d}.png", np.full((6, 8, 3), 255, np.uint8))
  read = load_llff(str(tmp_path), factor=2)
  np.testing.assert_array_equal(read.images, 1.0)
  assert read.intrinsics == (10.0, 10.0, 4.0, 3.0)


def test_load_dataset_detects_llff_and_holds_out_every_8th(forward, tmp_path):
  export_llff(forward, str(tmp_path))
  config = {"path": str(tmp_path), "holdout_from": -1}
  train, test = load_data(config)
  np.testing.assert_allclose(test.images, forward.images[[0, 8]], atol=Q)
  np.testing.assert_allclose(train.images, forward.images[[1, 2, 3, 4, 5, 6, 7, 9]], atol=Q)
  train, test = load_data({**config, "holdout_from": 7})
  assert (len(train), len(test)) == (7, 3)
  np.testing.assert_allclose(test.images, forward.images[7:], atol=Q)
  train, test = load_data({**config, "factor": 2})
  assert train.height == 6 and train.near == pytest.approx(1 / 0.75)  # default bd_factor 0.75
  centres = np.concatenate([train.poses, test.poses])[:, :3, 3]
  np.testing.assert_allclose(centres.mean(0), 0.0, atol=1e-6)  # recentred by default
  train, test = load_data({**config, "bd_factor": 0.0, "recenter": False})  # the file as is
  assert (train.near, train.far) == (forward.near, forward.far)
  np.testing.assert_allclose(test.poses, forward.poses[[0, 8]], atol=1e-5)


def test_errors(forward, tmp_path):
  root = tmp_path / "llff"
  export_llff(forward, str(root))
  table_path = str(root / "poses_bounds.npy")
  table = np.load(table_path)
  np.save(table_path, table[:, :15])
  _error([table_path, "(10, 15)", "[N, 17]"], load_llff, str(root))
  bad = table.copy()
  bad[2, 15] = -1.0
  np.save(table_path, bad)
  _error([table_path, "0 < near < far"], load_llff, str(root))
  bad[2, 15], bad[4, 7] = table[2, 15], np.nan
  np.save(table_path, bad)
  _error([table_path, "NaN"], load_llff, str(root))
  np.save(table_path, table[:9])
  _error(["images", "10 images", "9 views"], load_llff, str(root))
  np.save(table_path, table)
  os.rename(root / "images", root / "pictures")
  _error([str(root), "no images folder images/"], load_llff, str(root))
  _error(["no images folder images/"], load_data, {"path": str(root)})
  _error(["factor=1.5"], load_llff, str(root), factor=1.5)
  (root / "poses_bounds.npy").write_text("not an array")
  _error([table_path, "not a readable .npy"], load_llff, str(root))
  os.remove(table_path)
  _error(["poses_bounds.npy", "no such file"], load_llff, str(root))


def test_export_cli_writes_llff(tmp_path):
  out = str(tmp_path / "fwd")
  assert export.main(["--scene=forward", "--format=llff", f"--out={out}", "--num_views=3",
                      "--image_size=8"]) == 0
  back = load_llff(out)
  assert back.images.shape == (3, 8, 8, 3) and back.near == scenes.get_scene("forward").near


def test_spiral_poses_circle_the_centre_and_look_at_the_focus():
  centre = _rigid(_rotation([0.2, 1.0, 0.1], 25.0), [0.5, -0.2, 1.0])
  radii = np.array([0.3, 0.2, 0.1])
  poses = rays_lib.spiral_poses(centre, radii, focus_depth=4.0, num_frames=30, rotations=2)
  assert poses.shape == (30, 4, 4) and poses.dtype == np.float32
  rot = poses[:, :3, :3].astype(np.float64)
  np.testing.assert_allclose(rot.transpose(0, 2, 1) @ rot, np.broadcast_to(np.eye(3), rot.shape),
                             atol=1e-6)
  np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-6)
  focus = centre[:3, 3] - 4.0 * centre[:3, 2]
  to_focus = focus - poses[:, :3, 3]
  np.testing.assert_allclose(to_focus / np.linalg.norm(to_focus, axis=-1, keepdims=True),
                             -rot[:, :, 2], atol=1e-6)  # each camera's -z points at the focus
  for pose in poses[::7]:
    np.testing.assert_allclose(rays_lib.project(focus, 20, 30, 25.0, pose), [15.0, 10.0],
                               atol=1e-4)  # the focus is at the image centre
  np.testing.assert_allclose(poses[0, :3, 3], centre[:3, 3] + 0.3 * centre[:3, 0], atol=1e-6)
  offsets = (poses[:, :3, 3] - centre[:3, 3]) @ centre[:3, :3]  # in the centre camera's frame
  assert np.all(np.abs(offsets) <= radii + 1e-6)
  assert np.all(np.ptp(offsets, axis=0) > radii)  # the spiral spans its radii
  assert np.all(rot[:, :, 1] @ centre[:3, 1] > 0.95)  # no roll: up stays up


def test_llff_config_grids_hold_every_training_ray_in_ndc(forward, tmp_path):
  # configs/llff.py samples t in [0, 1] with no box cut: every sample of every training ray
  # must fall inside the grids' box found from the data, or parts of the photos would render
  # empty; and the box is no larger than the rays need. NDC rays are straight, so their ends
  # (t = 0 and t = 1) bound them; here they are checked at every pixel, not only the corners.
  from nerf_jax.run import experiment, from_data  # pylint: disable=import-outside-toplevel
  from tests.helpers import small_config  # pylint: disable=import-outside-toplevel
  export_llff(forward, str(tmp_path))
  config = small_config({"data.path": str(tmp_path), "data.factor": 1}, base="llff")
  exp = experiment.setup(config)
  assert config.data.ndc and exp.near == 0.0 and exp.far == 1.0
  assert not config.model.grid_box  # found at setup, recorded in the run's config
  box = np.asarray(exp.config.model.grid_box, np.float32).reshape(2, 3)
  points = np.concatenate([np.asarray(r.origins + t * r.directions).reshape(-1, 3)
                           for r in map(exp.rays, exp.train_ds.poses) for t in (0.0, 1.0)])
  low, high = points.min(axis=0), points.max(axis=0)
  assert np.all(box[0] <= low) and np.all(high <= box[1]), (box, low, high)
  np.testing.assert_allclose(box[1] - box[0], (high - low) * (1 + 2 * from_data.NDC_MARGIN),
                             rtol=1e-3)
