"""The visual hull: the space that the training masks do not rule out, found before any step.

A point can hold the scene only if every view that sees it sees opacity there. Carving the cells
of a grid over the scene box [-bound, bound]^3 against the masks (the alpha of RGBA data) gives
the hull; its bounding box is where the grids need their resolution, and the cells outside it
never need a sample (VaxNeRF). Names:
  accs:  float32 [N, H, W]  opacity of each pixel of the N training views
  poses: float32 [N, 4, 4]  camera-to-world (nerf_jax.cameras.rays conventions: the camera looks down -z)
  hull:  float32 [R, R, R]  1 where a cell may hold the scene, 0 where the masks rule it out
  masks: float32 [N, H, W] or None, the data's transient masks (Dataset.masks: 0 = ignore the
         pixel): a masked pixel says "unknown", not "empty", so it counts as covered and never
         carves a cell
The carving is conservative: each mask is dilated by the largest radius in pixels that a cell
projects to, so a cell that any structure touches (however thin) is never carved away.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.backend import precision
from nerf_jax.samplers import occupancy

OPAQUE = 0.01  # a pixel counts as covered from this opacity (anti-aliased edges included)


def project(points, pose, intrinsics, pixel_center=0.5):
  """Pixel coordinates of world points in one camera.

  points: float32 [..., 3]. pose: float32 [4, 4] camera-to-world. intrinsics: (fx, fy, cx, cy).
  Returns (column, row, depth): float32 [...] each; column and row are the continuous pixel
  indices whose ray passes through the point (`rays.pixel_rays` inverted), depth the distance in
  front of the camera along its -z axis (<= 0 behind it).
  """
  fx, fy, cx, cy = intrinsics
  local = precision.matmul(points - pose[:3, 3], pose[:3, :3])  # R^T (x - o), as row vectors
  depth = -local[..., 2]
  # Points at or behind the camera get depth 1e-9 here only to keep the division finite;
  # callers mask them out by `depth`.
  safe = jnp.maximum(depth, 1e-9)
  column = cx + fx * local[..., 0] / safe - pixel_center
  row = cy - fy * local[..., 1] / safe - pixel_center
  return column, row, depth


def dilation_radius(poses, intrinsics, bound, resolution):
  """Pixels (int) by which masks are dilated so that no touched cell is carved: the radius of a
  cell's circumscribed sphere, (√3/2)·cell, seen from the nearest distance any camera can have
  to a point of the box; None when a camera is inside the box's circumscribed sphere (no
  conservative radius exists: nothing is carved)."""
  cell = 2.0 * bound / resolution
  nearest = float(np.min(np.linalg.norm(np.asarray(poses)[:, :3, 3], axis=-1))) - math.sqrt(3) * bound
  if nearest <= cell:
    return None
  focal = max(intrinsics[0], intrinsics[1])
  return int(math.ceil(0.5 * math.sqrt(3) * cell * focal / nearest)) + 1


def carve(accs, poses, intrinsics, bound, resolution, pixel_center=0.5, masks=None):
  """The visual hull on the R^3 cells of the box [-bound, bound]^3 (module docstring).

  A cell is carved when some view sees its centre inside the image and the mask, dilated by
  `dilation_radius`, is empty there. Cells no view sees are kept; so are cells a view sees
  through a pixel its transient mask ignores (`masks`: such a pixel counts as opaque). Returns
  float32 [R, R, R] (all ones when no conservative dilation exists, see `dilation_radius`).
  """
  if masks is not None:
    accs = np.where(np.asarray(masks) > 0, np.asarray(accs), 1.0)  # unknown is not empty
  radius = dilation_radius(poses, intrinsics, bound, resolution)
  if radius is None:
    return jnp.ones((resolution,) * 3, jnp.float32)
  centres = occupancy.cell_centres(resolution, bound).reshape(-1, 3)
  height, width = accs.shape[1:]

  def keep_in_view(args):  # one view: bool [R^3], False where it rules the cell out
    acc, pose = args
    covered = dilated(acc, radius) > OPAQUE
    j, i, seen = pixels_seen(centres, pose, intrinsics, height, width, pixel_center)
    return ~seen | covered[j, i]

  keep = jax.jit(lambda a, p: jnp.all(jax.lax.map(keep_in_view, (a, p)), axis=0))(
      jnp.asarray(accs, jnp.float32), jnp.asarray(poses, jnp.float32))
  return keep.reshape((resolution,) * 3).astype(jnp.float32)


def bounding_box(hull, bound, margin=1):
  """float32 [2, 3]: (min, max) corners of the kept cells of `hull` [R, R, R] over the box
  [-bound, bound]^3, grown by `margin` cells on each side and clipped to the box; the whole box
  when nothing is kept."""
  res = hull.shape[0]
  kept = np.argwhere(np.asarray(hull) > 0)
  if len(kept) == 0:
    return np.array([[-bound] * 3, [bound] * 3], np.float32)
  cell = 2.0 * bound / res
  low = -bound + (kept.min(axis=0) - margin) * cell
  high = -bound + (kept.max(axis=0) + 1 + margin) * cell
  return np.clip(np.stack([low, high]), -bound, bound).astype(np.float32)


def dilated(mask, radius):
  """float32 [H, W]: the largest value of `mask` float32 [H, W] within `radius` pixels (a
  (2·radius + 1)^2 window; outside the image counts as nothing)."""
  window = (2 * radius + 1, 2 * radius + 1)
  return jax.lax.reduce_window(jnp.asarray(mask, jnp.float32), -jnp.inf, jax.lax.max, window,
                               (1, 1), "SAME")


def pixels_seen(points, pose, intrinsics, height, width, pixel_center):
  """(row, column) int32 [...] of the pixel each point float32 [..., 3] falls in (clamped to
  the image) and bool [...], whether it is in front of the camera and inside the image."""
  column, row, depth = project(points, pose, intrinsics, pixel_center)
  i, j = jnp.floor(column + 0.5).astype(jnp.int32), jnp.floor(row + 0.5).astype(jnp.int32)
  seen = (depth > 0) & (i >= 0) & (i < width) & (j >= 0) & (j < height)
  return jnp.clip(j, 0, height - 1), jnp.clip(i, 0, width - 1), seen


def carve_vote(masks, poses, cameras, bound, resolution, vote, pixel_center=0.5):
  """The hull of masks that keep a subject (a photo collection's, run/subject.py) on the R^3
  cells of the box [-bound, bound]^3: float32 [R, R, R], 1 where at least `vote` (a share) of
  the photos that see a cell's centre keep it, 0 elsewhere; a cell no photo sees is kept.

  Unlike `carve`, one photo does not decide: passers-by hide part of the subject in some photos
  and a zoom that the stored camera lacks moves its edges. Each mask is dilated by the radius
  in pixels that a cell projects to from that photo (`dilation_radius`), so a cell the subject
  touches counts as kept wherever the subject is seen; a photo taken from inside the box's
  circumscribed sphere has no such radius and does not vote.
  masks: float32 [N, H, W] or a list of [H_i, W_i] (1 = the subject). poses: float [N, 4, 4].
  cameras: Cameras (`camera(k)` gives photo k's size and intrinsics). vote: float in (0, 1].
  """
  centres = np.asarray(occupancy.cell_centres(resolution, bound), np.float64).reshape(-1, 3)
  seen, kept = np.zeros(len(centres)), np.zeros(len(centres))
  for k, pose in enumerate(np.asarray(poses, np.float64)):
    height, width, intrinsics = cameras.camera(k)
    radius = dilation_radius(pose[None], intrinsics, bound, resolution)
    if radius is None:
      continue
    cover = np.asarray(dilated(masks[k], radius)) > 0
    j, i, inside = (np.asarray(a) for a in pixels_seen(centres, pose, intrinsics, height, width,
                                                        pixel_center))
    seen += inside
    kept += inside & cover[j, i]
  return (kept >= vote * seen).reshape((resolution,) * 3).astype(np.float32)


def gate(hull, points, bound):
  """float32 [...]: 1 where points float32 [..., 3] lie in a kept cell of `hull` float32
  [R, R, R] over the box [-bound, bound]^3, 0 in a carved cell or outside the box (a subject's
  hull covers twice the box the subject was found to fill: run/from_data.subject_hull)."""
  inside = jnp.all(jnp.abs(points) <= bound, axis=-1)
  return jnp.where(inside, occupancy.lookup(hull, points, bound), 0.0)
