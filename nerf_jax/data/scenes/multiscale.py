"""`multiscale`: the `detail` scene seen by cameras at several distances and resolutions, with
exact ground truth: mip-NeRF's multiscale benchmark as a built-in scene.

View k is at level j = k mod LEVELS: (size / 2^j) pixels a side, focal / 2^j (the same field of
view), label str(j) and lossmult 4^j (mip-NeRF's area weighting); its camera orbits at a
distance drawn in [radius, (1 + SPREAD) · radius]. Every level is rendered by `tracer` with
3 × 3 rays per pixel of its own size (the ground truth of the pixel's footprint, whatever its
size), through the disk `cache` when large. far grows with the farthest camera.
"""

import dataclasses

import numpy as np

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data.dataset import Dataset
from nerf_jax.data.scenes import cache, detail

LEVELS = 4  # full, 1/2, 1/4 and 1/8 size, as mip-NeRF's multiscale Blender data
SPREAD = 0.75  # cameras from radius to (1 + SPREAD) x radius from the origin

SCENE = dataclasses.replace(detail.SCENE, name="multiscale")


def level_of(num_views):
  """int [num_views]: the scale level of each view (k mod LEVELS)."""
  return np.arange(num_views) % LEVELS


def make_dataset(poses, size, focal, pixel_center=0.5, near=None, far=None, seed=0):
  """The Dataset of `poses` (float32 [N, 4, 4] on the sphere of radius r around the origin,
  builtin.random_poses's), each moved out to its own distance and seen at its level (module
  docstring). size: int, level 0's height = width; focal: float, level 0's focal length."""
  num = len(poses)
  levels = level_of(num)
  radius = float(np.linalg.norm(poses[0][:3, 3]))
  scale = 1.0 + SPREAD * np.random.default_rng(seed + 1).uniform(0.0, 1.0, num)
  poses = np.array(poses, np.float32)
  poses[:, :3, 3] *= scale[:, None].astype(np.float32)
  near = SCENE.near if near is None else near
  far = SCENE.far + SPREAD * radius if far is None else far
  images, depths, accs = [None] * num, [None] * num, [None] * num
  cameras = [None] * num
  for j in range(LEVELS):
    views = np.flatnonzero(levels == j)
    if not len(views):
      continue
    side, f = max(1, size >> j), focal / 2 ** j
    out = cache.render_images(SCENE, poses[views], side, side, f, pixel_center, near, far)
    for n, k in enumerate(views):
      images[k], depths[k], accs[k] = out["rgb"][n], out["depth"][n], out["acc"][n]
      cameras[k] = (side, side, (float(f), float(f), side * 0.5, side * 0.5))
  return Dataset(images=[a.astype(np.float32) for a in images], poses=poses,
                 intrinsics=cameras[0][2], near=near, far=far,
                 depths=[a.astype(np.float32) for a in depths],
                 accs=[a.astype(np.float32) for a in accs], name=SCENE.name,
                 background=tuple(float(c) for c in SCENE.background),
                 pixel_center=float(pixel_center), image_cameras=Cameras.stack(cameras),
                 lossmult=4.0 ** levels, labels=levels)
