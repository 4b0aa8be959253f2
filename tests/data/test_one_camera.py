"""A camera per photo seen through one pinhole (data/one_camera.py), against images that are a
closed-form function of each pixel's ray direction."""

import numpy as np

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data.dataset import Dataset
from nerf_jax.run.auto import characterise

PIXEL_CENTER = 0.5


def sky(directions):
  """float [..., 3]: a smooth colour of the world direction (the image of a far panorama)."""
  d = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
  return 0.5 + 0.4 * np.stack([np.sin(3 * d[..., 0]), np.cos(2 * d[..., 1]), d[..., 2]], -1)


def photo(pose, height, width, intrinsics):
  """float32 [H, W, 3]: the panorama through a pinhole with `pose` (written out here: camera
  looking down -z, y up)."""
  fx, fy, cx, cy = intrinsics
  i, j = np.meshgrid(np.arange(width) + PIXEL_CENTER, np.arange(height) + PIXEL_CENTER)
  local = np.stack([(i - cx) / fx, -(j - cy) / fy, -np.ones_like(i)], -1)
  return sky(local @ pose[:3, :3].T).astype(np.float32)


def turned(angle):
  """float64 [4, 4]: a camera at the origin turned `angle` radians about y."""
  c, s = np.cos(angle), np.sin(angle)
  pose = np.eye(4)
  pose[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
  return pose


# Five photos of different sizes, zooms and principal points (a collection's cameras).
CAMERAS = [(48, 64, (70.0, 70.0, 32.0, 24.0)), (60, 40, (50.0, 52.0, 19.0, 31.0)),
           (40, 40, (120.0, 120.0, 20.0, 20.0)), (52, 70, (90.0, 90.0, 36.0, 25.0)),
           (44, 56, (65.0, 66.0, 28.5, 22.0))]


def collection(masked=False):
  poses = np.stack([turned(a) for a in np.linspace(-0.4, 0.4, len(CAMERAS))]).astype(np.float32)
  images = [photo(p, h, w, k) for p, (h, w, k) in zip(poses, CAMERAS)]
  masks = None
  if masked:  # keep the left half of each photo; photo 1 keeps only its columns from 30 on,
    # outside the shared view (which sees its columns 10.6 to 26.4)
    masks = [np.where(np.arange(w) < w // 2, 1.0, 0.0)[None].repeat(h, 0) for h, w, _ in CAMERAS]
    masks[1] = np.where(np.arange(40) >= 30, 1.0, 0.0)[None].repeat(60, 0)
  return Dataset(images=images, poses=poses, intrinsics=CAMERAS[0][2],
                 image_cameras=Cameras.stack(CAMERAS), masks=masks, near=0.1, far=10.0)


def test_each_photo_through_the_shared_pinhole_is_the_panorama_it_saw():
  data = collection()
  one = data.one_camera()  # one photo per camera: fewer than MIN_SHARED share image 0's
  assert len(one) == len(CAMERAS) and one.image_cameras is None
  height, width = one.images.shape[1:3]
  fx, fy, cx, cy = one.intrinsics
  # the median focal lengths; the field of view every photo covers (photo 2's: 20/120 a side)
  assert (fx, fy) == (70.0, 70.0)
  assert width == int(2 * 70.0 * 20 / 120) and (cx, cy) == (width / 2, height / 2)
  for k in range(len(CAMERAS)):
    truth = photo(np.asarray(data.poses[k], np.float64), height, width, one.intrinsics)
    # bilinear interpolation of a smooth image: the error is second order in a pixel's angle
    np.testing.assert_allclose(one.images[k], truth, atol=2e-3)


def test_a_photo_without_kept_pixels_in_the_shared_view_is_left_out():
  one = collection(masked=True).one_camera()
  assert len(one) == len(CAMERAS) - 1  # photo 1 keeps only pixels outside the shared view
  assert set(np.unique(one.masks)) <= {0.0, 1.0}
  width = one.images.shape[2]
  np.testing.assert_array_equal(one.masks[0][0], np.arange(width) < width // 2)


def test_images_that_share_a_camera_are_kept_as_they_are():
  cams = CAMERAS[:1] * 3 + CAMERAS[1:2]
  poses = np.stack([turned(a) for a in (0.0, 0.1, 0.2, 0.3)]).astype(np.float32)
  images = [photo(p, h, w, k) for p, (h, w, k) in zip(poses, cams)]
  data = Dataset(images=images, poses=poses, intrinsics=cams[0][2], image_cameras=Cameras.stack(cams))
  one = data.one_camera()
  assert len(one) == 3 and one.intrinsics == cams[0][2]
  np.testing.assert_array_equal(one.images, np.stack(images[:3]))


def test_a_collection_with_a_camera_per_photo_is_characterised():
  data = collection()
  decisions = characterise.decide(data)
  assert decisions is not None  # it returned None: one photo shared photo 0's camera
  assert {d.name for d in decisions} >= {"background", "forward", "appearance", "scales"}
