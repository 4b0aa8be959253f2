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


def footprint_radius(reach, camera, depth):
  """int64 [M]: `dilation_radius` point by point: the pixels that a ball of radius `reach`
  (world units) about each point spans in `camera` ((height, width, (fx, fy, cx, cy))), seen
  from its z-depth (float [M]) less `reach`, plus one; the image's larger side (any pixel)
  where the camera is within `reach` of the point."""
  height, width, (fx, fy, _, _) = camera
  focal = max(fx, fy)
  nearest = np.asarray(depth, np.float64) - reach
  # A camera within reach sees the ball anywhere: the whole image, and no division by <= 0.
  pixels = np.ceil(reach * focal / np.maximum(nearest, 1e-12)) + 1
  return np.where(nearest > 0, np.minimum(pixels, max(height, width)),
                  max(height, width)).astype(np.int64)


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
  return pixel_indices(*project(points, pose, intrinsics, pixel_center), height, width)


def pixel_indices(column, row, depth, height, width):
  """`pixels_seen` of a projection (`project`'s column, row, depth, float32 [...])."""
  i, j = jnp.floor(column + 0.5).astype(jnp.int32), jnp.floor(row + 0.5).astype(jnp.int32)
  seen = (depth > 0) & (i >= 0) & (i < width) & (j >= 0) & (j < height)
  return jnp.clip(j, 0, height - 1), jnp.clip(i, 0, width - 1), seen


def kept_within(mask, rows, columns, radius):
  """bool [M]: whether `mask` (float [H, W]) keeps a pixel (> 0) within `radius` (int, or int
  [M]; 0 = the pixel itself) rows and columns of each pixel (rows, columns int [M], inside the
  image): `dilated(mask, radius) > 0` there, read from the kept pixels' summed-area table so
  that each point may have its own radius (exact: integer counts)."""
  kept = np.asarray(mask) > 0
  table = np.zeros((kept.shape[0] + 1, kept.shape[1] + 1), np.int64)
  table[1:, 1:] = np.cumsum(np.cumsum(kept, 0), 1)
  rows, columns = np.asarray(rows, np.int64), np.asarray(columns, np.int64)
  top, bottom = np.maximum(rows - radius, 0), np.minimum(rows + radius, kept.shape[0] - 1) + 1
  left, right = np.maximum(columns - radius, 0), np.minimum(columns + radius,
                                                           kept.shape[1] - 1) + 1
  return (table[bottom, right] - table[top, right] - table[bottom, left] + table[top, left]) > 0


def mask_votes(masks, poses, cameras, points, radius, pixel_center=0.5):
  """(seen, kept) float64 [M]: for each world point float [M, 3], how many photos see it (in
  front of the camera, inside the image: `pixels_seen`, each photo through its own camera) and
  how many of those keep it (their mask keeps a pixel within `radius` pixels of the point's).
  The one mask vote of the code: the subject's box (run/subject.py), its hull (`carve_vote`) and
  the photos' zoom (run/photo_zoom.py) all count with it.

  masks: float32 [N, H, W] or a list of [H_i, W_i] (1 = the subject). poses: float [N, 4, 4].
  cameras: Cameras (`camera(k)` gives photo k's size and intrinsics). radius: function (k,
  depth float32 [M], the points' z-depths in photo k) -> int or int [M] (the window's radius in
  photo k's pixels), or None where photo k does not vote.
  """
  seen, kept = np.zeros(len(points)), np.zeros(len(points))
  for k, pose in enumerate(np.asarray(poses, np.float64)):
    height, width, intrinsics = cameras.camera(k)
    column, row, depth = project(points, pose, intrinsics, pixel_center)
    reach = radius(k, np.asarray(depth))
    if reach is None:
      continue
    j, i, inside = (np.asarray(a) for a in pixel_indices(column, row, depth, height, width))
    seen += inside
    kept += inside & kept_within(masks[k], j, i, reach)
  return seen, kept


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
  poses = np.asarray(poses, np.float64)
  radius = lambda k, depth: dilation_radius(poses[k][None], cameras.camera(k)[2], bound,
                                            resolution)
  seen, kept = mask_votes(masks, poses, cameras, centres, radius, pixel_center)
  return (kept >= vote * seen).reshape((resolution,) * 3).astype(np.float32)


def gate(hull, points, bound):
  """float32 [...]: 1 where points float32 [..., 3] lie in a kept cell of `hull` float32
  [R, R, R] over the box [-bound, bound]^3, 0 in a carved cell or outside the box (a subject's
  hull covers twice the box the subject was found to fill: run/from_data.subject_hull)."""
  inside = jnp.all(jnp.abs(points) <= bound, axis=-1)
  return jnp.where(inside, occupancy.lookup(hull, points, bound), 0.0)
