"""Photos of many cameras seen through one: each image resampled into a shared pinhole camera.

A photo collection gathered from many people has a camera of its own per photo (size, focal,
principal point), while the measurements `--config=auto` takes (run/auto/characterise.py, the
warm-up, the subject's box) read images of one camera. Keeping only the photos that share
image 0's camera leaves one photo of such a collection; instead every photo is resampled, from
the same camera centre and orientation, into one pinhole: the median focal length, and the
field of view that every photo covers (the narrowest photo's, about the principal point), so
no pixel of the result falls outside its photo. A pinhole seen through another pinhole with
the same pose is an axis-aligned scale and shift of pixel coordinates, so the resampling is
exact up to the bilinear interpolation of the photo's pixels.

Names: cameras: Cameras of the N photos (pinhole: the loaders undistort); pixel_center: float,
where in its pixel each image was sampled (`cameras.rays`).
"""

import dataclasses

import numpy as np

from nerf_jax.data import resampling


def common_pinhole(cameras):
  """(height, width, (fx, fy, cx, cy)): the median focal lengths of `cameras` and the largest
  centred field of view inside every one of them (each side's angle: the smallest over the
  photos of the principal point's distance to that edge over the focal length)."""
  fx, fy = float(np.median(cameras.fx)), float(np.median(cameras.fy))
  half_x = np.min(np.minimum(cameras.cx, cameras.width - cameras.cx) / cameras.fx)
  half_y = np.min(np.minimum(cameras.cy, cameras.height - cameras.cy) / cameras.fy)
  width, height = max(1, int(2 * half_x * fx)), max(1, int(2 * half_y * fy))
  return height, width, (fx, fy, 0.5 * width, 0.5 * height)


def source_coordinates(target, source, pixel_center):
  """(rows float64 [H], columns float64 [W]): where each row and column of the `target` camera
  falls in the `source` photo, as continuous pixel indices (pixel k's value sits at index k).
  target, source: (height, width, (fx, fy, cx, cy)), `Cameras.camera`'s form. The two share a
  pose, so a pixel's normalised coordinate (index + pixel_center - c) / f is the same in both."""
  height, width, (fx, fy, cx, cy) = target
  _, _, (sfx, sfy, scx, scy) = source
  columns = scx + sfx * (np.arange(width) + pixel_center - cx) / fx - pixel_center
  rows = scy + sfy * (np.arange(height) + pixel_center - cy) / fy - pixel_center
  return rows, columns


def nearest(image, rows, columns):
  """`image` [h, w, ...] at the nearest pixel of each point of the grid rows [H] x columns [W]
  (for masks and depths, whose values must not blend across an edge)."""
  r = np.clip(np.floor(rows + 0.5).astype(int), 0, image.shape[0] - 1)
  c = np.clip(np.floor(columns + 0.5).astype(int), 0, image.shape[1] - 1)
  return np.asarray(image)[r][:, c]


def resampled(dataset):
  """`dataset` (a Dataset with per-image cameras) with every image, opacity, depth and mask
  resampled into `common_pinhole(dataset.cameras)`: a Dataset of one camera (`images` float32
  [M, H, W, 3], image_cameras None); poses and everything scene-wide unchanged. Masks stay 0/1
  (nearest pixel); so do depths, which a shared camera centre and orientation leave unchanged.
  The photos whose masks keep no pixel of the shared view are left out (M <= N)."""
  target = common_pinhole(dataset.cameras)
  bilinear = lambda image, rows, columns: resampling.bilinear(  # on the grid, in float32
      np.asarray(image, np.float32), rows[:, None], columns[None, :])
  grids = [source_coordinates(target, dataset.cameras.camera(k), dataset.pixel_center)
           for k in range(len(dataset))]

  def each(values, sample):
    if values is None:
      return None
    return np.stack([sample(v, *grid) for v, grid in zip(values, grids)]).astype(np.float32)

  masks = each(dataset.masks, nearest)
  seen = np.ones(len(dataset), bool) if masks is None else masks.reshape(len(masks), -1).any(1)
  take = lambda a: None if a is None else a[seen]  # a photo whose kept pixels all lie
  # outside the shared view says nothing through it (and a Dataset holds no all-masked image)
  return dataclasses.replace(dataset.subset(np.flatnonzero(seen)),
                             images=take(each(dataset.images, bilinear)),
                             accs=take(each(dataset.accs, bilinear)),
                             depths=take(each(dataset.depths, nearest)), masks=take(masks),
                             intrinsics=target[2], image_cameras=None)


def shared_or_resampled(dataset, min_shared):
  """The images of `dataset` that share image 0's camera, as a Dataset of one camera; where
  fewer than `min_shared` (int) share it (a photo collection: a camera per photo), every image
  resampled into one pinhole (`resampled`)."""
  cameras = dataset.image_cameras
  if cameras is None:
    return dataset
  first = cameras.camera(0)
  same = np.flatnonzero([cameras.camera(k) == first for k in range(len(dataset))])
  if len(same) < min_shared:
    return resampled(dataset)
  part = dataset.subset(same)
  stack = lambda a: a if a is None or not isinstance(a, list) else np.stack(a)
  return dataclasses.replace(part, images=stack(part.images), accs=stack(part.accs),
                             depths=stack(part.depths), masks=stack(part.masks),
                             image_cameras=None)

