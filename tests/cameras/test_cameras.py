"""Tests of nerf_jax.cameras.cameras (per-image cameras) and of Dataset.cameras: each image's
rays against a brute-force loop over its pixels."""

import jax.numpy as jnp
import numpy as np

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data.dataset import Dataset

# Three cameras: different sizes, focal lengths and principal points.
CAMS = [(6, 8, (9.0, 7.5, 4.0, 3.0)), (3, 4, (4.5, 4.0, 2.25, 1.5)), (5, 5, (6.0, 6.0, 2.0, 3.5))]
RNG = np.random.default_rng(0)


def _pose(seed):
  q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
  pose = np.eye(4)
  pose[:3, :3], pose[:3, 3] = q, np.random.default_rng(seed + 1).normal(size=3)
  return pose.astype(np.float32)


def _brute_ray(pose, intrinsics, col, row, pixel_center=0.5):
  """One pixel's (origin, direction) by the conventions of cameras/rays.py, in float64."""
  fx, fy, cx, cy = intrinsics
  cam = np.array([(col + pixel_center - cx) / fx, -(row + pixel_center - cy) / fy, -1.0])
  return pose[:3, 3].astype(np.float64), pose[:3, :3].astype(np.float64) @ cam


def test_cameras_stack_give_back_each_camera_and_subset():
  cams = Cameras.stack(CAMS)
  assert len(cams) == 3 and [cams.camera(k) for k in range(3)] == CAMS
  assert cams.subset([2, 0]).camera(0) == CAMS[2] and not cams.is_shared()
  assert not cams.same_size() and list(cams.num_pixels()) == [48, 12, 25]
  np.testing.assert_array_equal(cams.table()[1], np.float32(CAMS[1][2]))
  shared = Cameras.shared(4, 6, 8, CAMS[0][2])
  assert shared.is_shared() and shared.same_size() and shared.camera(3) == CAMS[0]


def test_a_datasets_cameras_come_from_its_intrinsics_with_one_camera():
  ds = Dataset(np.zeros((2, 6, 8, 3), np.float32), np.stack([_pose(0)] * 2), CAMS[0][2])
  assert ds.image_cameras is None and ds.cameras.camera(1) == CAMS[0]
  # Per-image cameras that are all one camera are dropped: today's one-camera path.
  same = Dataset(ds.images, ds.poses, (1.0, 1.0, 1.0, 1.0),
                 image_cameras=Cameras.shared(2, 6, 8, CAMS[0][2]))
  assert same.image_cameras is None and same.intrinsics == CAMS[0][2]


def test_images_of_different_sizes_are_a_list_with_their_own_cameras():
  images = [RNG.uniform(size=(h, w, 3)).astype(np.float32) for h, w, _ in CAMS]
  ds = Dataset(images, np.stack([_pose(k) for k in range(3)]), CAMS[0][2],
               image_cameras=Cameras.stack(CAMS), lossmult=[1, 4, 16], labels=[0, 1, 2])
  assert ds.mixed_sizes and len(ds) == 3 and (ds.height, ds.width) == (6, 8)
  part = ds.subset([2, 1])
  assert part.intrinsics == CAMS[2][2] and part.cameras.camera(1) == CAMS[1]
  assert part.image(0) is images[2] and list(part.labels) == ["2", "1"]
  np.testing.assert_array_equal(part.lossmult, [16, 4])


def test_each_images_rays_match_a_loop_over_its_pixels():
  for k, (height, width, intrinsics) in enumerate(CAMS):
    pose = _pose(k)
    rays = rays_lib.camera_rays(height, width, intrinsics, pose, 2.0, 6.0, 0.5)
    for row in range(height):
      for col in range(width):
        origin, direction = _brute_ray(pose, intrinsics, col, row)
        np.testing.assert_allclose(rays.origins[row, col], origin, atol=1e-6)
        np.testing.assert_allclose(rays.directions[row, col], direction, rtol=1e-5, atol=1e-6)


def test_pixel_rays_take_per_ray_intrinsics():
  """pixel_rays broadcasts intrinsics arrays: rays of pixels of several cameras in one call."""
  cams = Cameras.stack(CAMS)
  image = np.array([0, 1, 2, 2, 0, 1])
  col, row = np.array([7, 3, 0, 4, 0, 1]), np.array([5, 2, 4, 0, 0, 1])
  pose = _pose(3)
  table = cams.table()[image]
  rays = rays_lib.pixel_rays(jnp.asarray(col, jnp.float32), jnp.asarray(row, jnp.float32), 0, 0,
                             tuple(jnp.asarray(table[:, c]) for c in range(4)), pose, 2.0, 6.0)
  for n in range(len(image)):
    _, direction = _brute_ray(pose, CAMS[image[n]][2], col[n], row[n])
    np.testing.assert_allclose(rays.directions[n], direction, rtol=1e-5, atol=1e-6)
