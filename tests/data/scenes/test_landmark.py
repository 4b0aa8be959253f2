"""Tests of the built-in `landmark` scene (scenes/landmark.py): a monument photographed from 2 to
9 times its size, each training photo through its own zoom and radial lens while the data
stores one pinhole, per-photo looks, passers-by, and masks of the subject; against references
computed here (bounding boxes, a bisection inverse of the Brown-Conrady polynomial, rays cast
with the simulator)."""

import os

import numpy as np
import pytest

from nerf_jax.data import export, loaders, scenes
from nerf_jax.data.llff import load_llff
from nerf_jax.data.scenes import landmark, occluders, photos, simulator
from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from nerf_jax.run import builders

VIEWS, SIZE = 30, 32
FOCAL = scenes.TINY_NERF_FOCAL * SIZE / 100  # the stored focal the loader asks for


@pytest.fixture(scope="module")
def loaded():
  """(train, test) as the loader gives them, and the clean views of make_dataset."""
  train, test = loaders.load_dataset(builders.data_settings(
      {"scene": "landmark", "num_views": VIEWS, "image_size": SIZE}))
  clean = scenes.make_dataset("landmark", VIEWS, SIZE, SIZE, FOCAL)
  return train, test, clean


@pytest.fixture(scope="module")
def lens_only(loaded):
  """The training views through their own lenses, without passers-by, and with them."""
  clean_train = loaded[2].split()[0]
  return (landmark.photographed(clean_train, transients=False)[0],
          landmark.photographed(clean_train, transients=True))


def _box(shape):
  """(min, max) float64 [3] of a shape's axis-aligned bounding box."""
  c = np.asarray(shape.center, np.float64)
  if isinstance(shape, Box):
    half = 0.5 * np.asarray(shape.size)
  elif isinstance(shape, Sphere):
    half = np.full(3, shape.radius)
  else:
    assert isinstance(shape, Cylinder)  # a vertical axis
    half = np.array([shape.radius, shape.radius, 0.5 * shape.height])
  return c - half, c + half


def _undistort_by_bisection(xy_d, k1, k2):
  """Pinhole coordinates float64 [P, 2] of distorted ones: r_d = r (1 + k1 r² + k2 r⁴) solved
  for r by bisection (the polynomial rises for the scene's lenses), the direction kept."""
  r_d = np.linalg.norm(xy_d, axis=-1)
  lo, hi = np.zeros_like(r_d), np.full_like(r_d, 10.0)
  for _ in range(200):
    mid = 0.5 * (lo + hi)
    low = mid * (1 + k1 * mid**2 + k2 * mid**4) < r_d
    lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
  r = 0.5 * (lo + hi)
  return xy_d * np.where(r_d > 0, r / np.maximum(r_d, 1e-300), 1.0)[:, None]


def _rays(pose, focal, k1, k2, pixels):
  """World rays (origins, directions float64 [P, 3], z-depth parameter) of pixel centres
  `pixels` int [P, 2] (column, row) of a SIZE x SIZE photo through (focal, k1, k2)."""
  xy_d = (pixels + 0.5 - 0.5 * SIZE) / focal  # y down, as OpenCV
  xy = _undistort_by_bisection(xy_d, k1, k2)
  cam = np.stack([xy[:, 0], -xy[:, 1], -np.ones(len(xy))], -1)  # ours: y up, looking down -z
  pose = np.asarray(pose, np.float64)
  return np.broadcast_to(pose[:3, 3], cam.shape), cam @ pose[:3, :3].T


def _project(points, pose, focal, k1, k2):
  """Pixel coordinates float64 [P, 2] of world points [P, 3] through the distorted camera."""
  pose = np.asarray(pose, np.float64)
  cam = (points - pose[:3, 3]) @ pose[:3, :3]
  x, y = cam[:, 0] / -cam[:, 2], -cam[:, 1] / -cam[:, 2]
  r2 = x * x + y * y
  radial = 1 + k1 * r2 + k2 * r2 * r2
  return np.stack([focal * x * radial, focal * y * radial], -1) + 0.5 * SIZE


def _all_pixels():
  j, i = np.mgrid[:SIZE, :SIZE]
  return np.stack([i.ravel(), j.ravel()], -1)


def test_the_subject_is_a_fifth_of_the_camera_distances():
  assert landmark.SCENE.objects[:len(landmark.SUBJECT)] == landmark.SUBJECT
  boxes = [_box(o.shape) for o in landmark.SUBJECT]
  low, high = np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)
  size, centre = np.max(high - low), 0.5 * (low + high)
  np.testing.assert_allclose(size, landmark.SIZE, atol=1e-12)
  np.testing.assert_allclose(centre, 0.0, atol=1e-12)
  assert low[2] == landmark.GROUND_Z  # it stands on the square
  poses = landmark.poses(500, seed=3)
  offset = poses[:, :3, 3].astype(np.float64) - centre
  ratio = np.linalg.norm(offset, axis=-1) / size
  assert ratio.min() >= 2.0 - 1e-5 and ratio.max() <= 9.0 + 1e-5
  assert ratio.min() < 2.1 and ratio.max() > 8.5 and 4.0 < np.median(ratio) < 5.0
  elevation = np.degrees(np.arcsin(offset[:, 2] / np.linalg.norm(offset, axis=-1)))
  assert elevation.min() >= 5.0 - 1e-4 and elevation.max() <= 30.0 + 1e-4
  azimuth = np.degrees(np.arctan2(offset[:, 1], offset[:, 0]))
  assert np.histogram(azimuth, 8, (-180, 180))[0].min() > 30  # all around it
  forward = -poses[:, :3, 2]  # each camera looks at the subject's centre
  np.testing.assert_allclose(forward, -offset / np.linalg.norm(offset, axis=-1)[:, None],
                             atol=1e-5)
  assert landmark.SCENE.effects.names() == {"unbounded", "appearance", "transients", "lens"}


def test_one_stored_pinhole_and_per_photo_zoom_and_lens(loaded):
  train, test, _ = loaded
  for part in (train, test):
    assert part.image_cameras is None
    assert part.intrinsics == (FOCAL, FOCAL, 0.5 * SIZE, 0.5 * SIZE)
    assert part.pinhole_focal() == FOCAL
  focals, dist = landmark.lenses(len(train), FOCAL)
  np.testing.assert_allclose(focals.max() / focals.min(), 3.0, rtol=1e-12)
  np.testing.assert_allclose(np.median(focals), FOCAL, rtol=1e-3)  # even count: within 0.1%
  steps = np.diff(np.sort(np.log(focals)))  # log-uniform: evenly spaced logs
  np.testing.assert_allclose(steps, np.log(3.0) / (len(train) - 1), rtol=1e-9)
  k1, k2 = dist[:, 0], dist[:, 1]
  assert np.all((k1 >= -0.5) & (k1 <= -0.2)) and k1.max() - k1.min() > 0.15
  np.testing.assert_allclose(k2, 0.6 * k1**2)
  r = np.linspace(0.0, 5.0, 5001)[:, None]  # every pixel has one ray: r_d(r) rises
  assert np.all(np.diff(r * (1 + k1 * r**2 + k2 * r**4), axis=0) > 0)
  cameras, opencv = landmark.true_cameras(train)
  np.testing.assert_array_equal(cameras.fx, focals)
  np.testing.assert_array_equal(opencv, np.concatenate([dist, np.zeros_like(dist)], -1))


def test_each_pixel_shows_what_the_distorted_projection_maps_there(loaded, lens_only):
  photographed = lens_only[0]
  focals, dist = landmark.lenses(len(photographed), FOCAL)
  pixels, shifts = _all_pixels(), []
  for k in {int(np.argmin(focals)), int(np.argmin(dist[:, 0])), 5}:  # widest, most barrel
    (k1, k2), pose = dist[k], photographed.poses[k]
    origins, directions = _rays(pose, focals[k], k1, k2, pixels)
    truth = simulator.trace_rays(landmark.SCENE, origins, directions, landmark.NEAR,
                                 landmark.FAR)
    assert np.all(truth["acc"] == 1.0)  # the square is closed
    np.testing.assert_allclose(photographed.images[k].reshape(-1, 3), truth["rgb"], atol=2e-6)
    np.testing.assert_allclose(photographed.depths[k].reshape(-1), truth["depth"], rtol=1e-6)
    # The point each pixel shows projects back onto its centre through the distorted camera ...
    points = origins + truth["depth"][:, None] * directions
    np.testing.assert_allclose(_project(points, pose, focals[k], k1, k2), pixels + 0.5,
                               atol=1e-6)
    # ... and a pinhole of the same focal would put the corners' points away from theirs.
    shifts.append(np.abs(_project(points, pose, focals[k], 0.0, 0.0) - pixels - 0.5).max())
  assert min(shifts) > 0.25 and max(shifts) > 3.0  # pixels of a 32-pixel photo
  # The held-out views: the pinhole of the stored focal, the static scene, the neutral look.
  train, test, clean = loaded
  np.testing.assert_array_equal(test.images, clean.split()[1].images)
  k = 2
  origins, directions = _rays(test.poses[k], FOCAL, 0.0, 0.0, pixels)
  truth = simulator.trace_rays(landmark.SCENE, origins, directions, landmark.NEAR, landmark.FAR)
  np.testing.assert_allclose(test.images[k].reshape(-1, 3), truth["rgb"], atol=2e-6)


def test_masks_are_the_pixels_whose_first_hit_is_the_subject(loaded, lens_only):
  train, test, clean = loaded
  photographed, passers = lens_only[1]
  focals, dist = landmark.lenses(len(train), FOCAL)
  pixels, subject_count = _all_pixels(), len(landmark.SUBJECT)
  crowded = np.flatnonzero(occluders.crowded_views(len(train)))
  hidden = 0
  for views, cameras, indices in ((test, lambda k: (FOCAL, 0.0, 0.0), range(4)),
                                  (train, lambda k: (focals[k], *dist[k]),
                                   [0, 1, *crowded[:4]])):
    for k in indices:
      origins, directions = _rays(views.poses[k], *cameras(k), pixels)
      t, index, _ = simulator.first_hit(landmark.SCENE.objects, origins, directions,
                                        landmark.NEAR, landmark.FAR)
      subject = (index >= 0) & (index < subject_count)
      # Seen unless something nearer (a passer-by) stands in front.
      seen = views.depths[k].reshape(-1) >= t * (1 - 1e-6)
      np.testing.assert_array_equal(views.masks[k].reshape(-1), subject & seen)
      assert 0 < subject.mean() < 1
      hidden += np.sum(subject & ~seen)
  assert hidden > 0  # passers-by stand before the subject in some of the photos checked
  np.testing.assert_array_equal(train.masks, photographed.masks)
  np.testing.assert_array_equal(test.masks, clean.split()[1].masks)
  assert 0.03 < train.masks.mean() < 0.3 and 0.03 < test.masks.mean() < 0.3


def test_passers_by_only_in_the_photos_that_have_them(loaded, lens_only):
  train = loaded[0]
  alone, (photographed, passers) = lens_only
  crowded = occluders.crowded_views(len(train))
  assert crowded.sum() == round(occluders.SHARE * len(train))
  assert np.array_equal(passers.any(axis=(1, 2)), crowded)
  np.testing.assert_array_equal(photographed.images[~passers], alone.images[~passers])
  assert np.abs(photographed.images[passers] - alone.images[passers]).max() > 0.1
  assert np.all(photographed.depths[passers] < alone.depths[passers])  # in front
  # A crowd hides at most half of the subject.
  kept = photographed.masks.sum(axis=(1, 2)) / alone.masks.sum(axis=(1, 2))
  assert kept.min() >= 0.5 and kept[~crowded].min() == 1.0
  # The loader's photos are these under each photo's own look.
  looks = photos.with_gains(photographed.images, photos.gains(len(train)))
  np.testing.assert_array_equal(train.images, looks)


def test_the_same_seed_gives_the_same_photos(loaded):
  clean_train = loaded[2].split()[0]
  first, again = (landmark.photographed(clean_train, seed=4)[0] for _ in range(2))
  for name in ("images", "depths", "masks"):
    np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
  other = landmark.photographed(clean_train, seed=5)[0]
  assert np.abs(other.images - first.images).max() > 0.1
  np.testing.assert_array_equal(scenes.make_dataset("landmark", 4, 16, 16, seed=7).images,
                                scenes.make_dataset("landmark", 4, 16, 16, seed=7).images)


def test_llff_export_holds_one_focal_and_the_masks(loaded, tmp_path):
  views, size = 10, 16
  assert export.main(["--scene=landmark", "--format=llff", f"--out={tmp_path}",
                      f"--num_views={views}", f"--image_size={size}"]) == 0
  table = np.load(os.path.join(tmp_path, "poses_bounds.npy"))
  focal = scenes.TINY_NERF_FOCAL * size / 100
  hwf = table[:, :15].reshape(-1, 3, 5)[:, :, 4]
  np.testing.assert_array_equal(hwf, np.tile([size, size, focal], (views, 1)))
  assert sorted(os.listdir(tmp_path / "masks")) == [f"{k:03d}.png" for k in range(views)]
  train, test = loaders.load_dataset(builders.data_settings(
      {"scene": "landmark", "num_views": views, "image_size": size}))
  read = load_llff(str(tmp_path), bd_factor=None, recenter=False)
  np.testing.assert_array_equal(read.masks, np.concatenate([train.masks, test.masks]))
  np.testing.assert_allclose(read.images, np.concatenate([train.images, test.images]),
                             atol=0.5 / 255 + 1e-6)
  np.testing.assert_allclose(read.poses, np.concatenate([train.poses, test.poses]), atol=1e-6)


def test_each_part_of_the_capture_can_be_left_out_alone():
  focals, dists = landmark.lenses(9, 50.0)
  no_zoom = landmark.lenses(9, 50.0, zoom=False)
  pinhole = landmark.lenses(9, 50.0, distortion=False)
  np.testing.assert_array_equal(no_zoom[0], 50.0)  # the stored focal is every photo's
  np.testing.assert_array_equal(no_zoom[1], dists)  # the lenses drawn as before
  np.testing.assert_array_equal(pinhole[0], focals)
  np.testing.assert_array_equal(pinhole[1], 0.0)
  effects = landmark.SCENE.effects
  less, parts = scenes.without(effects, " zoom, transients")
  assert parts == ("distortion",) and not less.transients
  assert less.names() == effects.names() - {"transients"}
  assert scenes.without(effects, "") == (effects, photos.LENS_PARTS)
  assert scenes.without(effects, "lens,appearance")[0].names() == effects.names() - {
      "lens", "appearance"}


def test_a_misspelt_effect_is_one_line_naming_the_field():
  with pytest.raises(loaders.DataError, match="data.without: unknown zoomm"):
    loaders.load_dataset(loaders.DataSettings(scene="landmark", without="zoomm"))
