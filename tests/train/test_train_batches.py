"""Tests of nerf_jax.train.train_batches' path for images with cameras of their own: the flat
draws cover every pixel of every image, each with its image's colour, ray and lossmult."""

import dataclasses

import jax
import numpy as np
import pytest

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data.dataset import Dataset
from nerf_jax.train import train_batches

CAMS = [(6, 8, (9.0, 7.5, 4.0, 3.0)), (3, 4, (4.5, 4.0, 2.25, 1.5)), (5, 5, (6.0, 6.0, 2.0, 3.5))]
LOSSMULT = [1.0, 4.0, 16.0]


def _dataset():
  rng = np.random.default_rng(0)
  images = [rng.uniform(size=(h, w, 3)).astype(np.float32) for h, w, _ in CAMS]
  poses = []
  for k in range(len(CAMS)):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    pose = np.eye(4, dtype=np.float32)
    pose[:3, :3], pose[:3, 3] = q, rng.normal(size=3)
    poses.append(pose)
  return Dataset(images, np.stack(poses), CAMS[0][2], image_cameras=Cameras.stack(CAMS),
                 lossmult=LOSSMULT)


def _data(ds):
  return train_batches.make_train_data(ds, (6, 8, CAMS[0][2], 2.0, 6.0, 0.5, False),
                                       np.zeros(3, np.float32))


def test_flat_draws_cover_every_images_pixels_with_their_rays():
  ds = _dataset()
  data = _data(ds)
  assert data.rgb.shape == (48 + 12 + 25, 3) and list(data.offsets) == [0, 48, 60]
  settings = train_batches.BatchSettings(batch_rays=512)
  draw = jax.jit(lambda key: train_batches.draw_batch(data, settings, key))
  seen, counts = set(), np.zeros(3)
  for s in range(4):
    batch = jax.tree_util.tree_map(np.asarray, draw(jax.random.PRNGKey(s)))
    for n in range(0, 512, 7 if s else 1):  # every ray of the first batch, a sample of others
      k, p = int(batch.image[n]), int(batch.pixel[n])
      height, width, (fx, fy, cx, cy) = CAMS[k]
      row, col = divmod(p, width)
      assert 0 <= p < height * width
      np.testing.assert_array_equal(batch.rgb[n], ds.images[k][row, col])
      cam = np.array([(col + 0.5 - cx) / fx, -(row + 0.5 - cy) / fy, -1.0])
      pose = ds.poses[k].astype(np.float64)
      np.testing.assert_allclose(batch.rays.directions[n], pose[:3, :3] @ cam, rtol=1e-5,
                                 atol=1e-6)
      np.testing.assert_allclose(batch.rays.origins[n], pose[:3, 3], atol=1e-6)
      assert batch.weight[n] == LOSSMULT[k]
    seen.update(zip(batch.image.tolist(), batch.pixel.tolist()))
    counts += np.bincount(batch.image, minlength=3)
  assert seen == {(k, p) for k, (h, w, _) in enumerate(CAMS) for p in range(h * w)}
  # Every pixel equally likely: each image drawn in proportion to its pixels (4 sigma).
  share = np.array([48, 12, 25]) / 85
  total = counts.sum()
  assert np.all(np.abs(counts - total * share) < 4 * np.sqrt(total * share))


def test_pose_corrections_reach_the_flat_rays():
  ds = _dataset()
  data = _data(ds)
  image, pixel = np.array([0, 1, 2]), np.array([5, 7, 24])
  moved = np.array(ds.poses)
  moved[:, :3, 3] += 1.0
  rays = train_batches.pixel_rays_of(data, image, pixel, moved)
  np.testing.assert_allclose(rays.origins, moved[image, :3, 3], atol=1e-6)


def test_whole_image_batches_of_different_cameras_are_refused():
  data = _data(_dataset())
  with pytest.raises(ValueError, match="config.train.batching='images'"):
    train_batches.draw_batch(data, train_batches.BatchSettings(batching="images"),
                             jax.random.PRNGKey(0))


def test_one_camera_data_keep_their_rows_and_draw_no_weight():
  ds = Dataset(np.zeros((2, 6, 8, 3), np.float32), np.stack([np.eye(4, dtype=np.float32)] * 2),
               CAMS[0][2])
  data = _data(ds)
  assert data.offsets is None and data.rgb.shape == (2, 48, 3)
  batch = train_batches.draw_batch(data, train_batches.BatchSettings(batch_rays=8),
                                   jax.random.PRNGKey(0))
  assert batch.weight is None


@pytest.mark.parametrize("own_cameras", [True, False])
def test_each_photos_rays_are_sampled_within_its_own_bounds(own_cameras):
  ds = _dataset()
  if not own_cameras:  # one shared camera: every image 6 x 8
    ds = Dataset(np.stack([np.resize(im, (6, 8, 3)) for im in ds.images]), ds.poses, CAMS[0][2])
  bounds = np.array([[1.0, 3.0], [2.5, 4.0], [0.5, 9.0]], np.float32)
  ds = dataclasses.replace(ds, bounds=bounds)
  image, pixel = np.array([2, 0, 1, 2, 0]), np.array([3, 5, 7, 11, 0])
  shared = train_batches.pixel_rays_of(_data(ds), image, pixel)
  own = train_batches.pixel_rays_of(train_batches.make_train_data(
      ds, (6, 8, CAMS[0][2], 2.0, 6.0, 0.5, False), np.zeros(3, np.float32),
      photo_bounds=True), image, pixel)
  np.testing.assert_array_equal(shared.near, 2.0)
  np.testing.assert_array_equal(shared.far, 6.0)
  np.testing.assert_array_equal(own.near, bounds[image, 0])  # the drawn photo's, ray by ray
  np.testing.assert_array_equal(own.far, bounds[image, 1])
  np.testing.assert_array_equal(own.directions, shared.directions)
  with pytest.raises(ValueError, match="data.photo_bounds"):
    train_batches.make_train_data(dataclasses.replace(ds, bounds=None),
                                  (6, 8, CAMS[0][2], 2.0, 6.0, 0.5, False),
                                  np.zeros(3, np.float32), photo_bounds=True)


def test_patches_of_one_size_with_cameras_of_their_own_use_each_images_camera():
  """A collection posed a camera per photo, all of one size (zooms differ): rows of pixels,
  patches allowed (the trimmed loss), each ray through its own photo's focal and centre."""
  cams = [(6, 8, (9.0, 7.5, 4.0, 3.0)), (6, 8, (18.0, 15.0, 3.0, 2.5)), (6, 8, (5.0, 5.0, 4.5, 3.0))]
  rng = np.random.default_rng(1)
  ds = Dataset(rng.uniform(size=(3, 6, 8, 3)).astype(np.float32), _dataset().poses, cams[0][2],
               image_cameras=Cameras.stack(cams))
  data = _data(ds)
  assert data.offsets is None and data.rgb.shape == (3, 48, 3)
  settings = train_batches.BatchSettings(batch_rays=64, batching="patches", patch_size=4)
  batch = jax.tree_util.tree_map(np.asarray, train_batches.draw_batch(data, settings,
                                                                      jax.random.PRNGKey(3)))
  assert len(batch.image) == 64 and len(set(batch.image.tolist())) > 1
  for n in range(64):
    k, (row, col) = int(batch.image[n]), divmod(int(batch.pixel[n]), 8)
    _, _, (fx, fy, cx, cy) = cams[k]
    np.testing.assert_array_equal(batch.rgb[n], ds.images[k][row, col])
    cam = np.array([(col + 0.5 - cx) / fx, -(row + 0.5 - cy) / fy, -1.0])
    np.testing.assert_allclose(batch.rays.directions[n], ds.poses[k, :3, :3].astype(np.float64)
                               @ cam, rtol=1e-5, atol=1e-6)
