"""`landmark_sfm`: landmark's photos posed as a structure from motion forced to ONE shared focal
poses them (`Effects.sfm_poses`).

A real collection's poses come from a reconstruction, and a reconstruction that shares one
pinhole between photos taken at many zooms cannot give their true poses: to match a zoomed-in
photo it moves that camera along its axis, closer to the subject (farther for a wide one), and
the poses absorb the zooms and the lenses. `landmark` stores its true poses; this twin stores
what such a reconstruction gives, everything else unchanged (the same renders, zooms, lenses,
passers-by, looks and masks: `photos.photographed` applies it after them).

Each training photo's pose is solved on its own (`solved_pose`): the 6-DoF camera that
minimises the reprojection error, through the stored pinhole (the median focal, no
distortion), of the 3D points the photo really sees (`matched_points`):
  * where: a GRID x GRID grid of pixels (the same share of every photo at any size);
  * which: the static surfaces a real SfM matches between photos: the monument AND the
    square's ground and façades; not the sky (textured here, but a real sky gives no stable
    features) and not the passers-by (they move between photos), known from the scene;
  * the points: the photo's true depth (Dataset.depths) back-projected through its TRUE camera
    (its own focal and lens, `landmark.lenses`), at the pixel where the photo shows them (the
    observed, distorted pixel);
  * the solve: Levenberg-Marquardt from the true pose (no robustness to bad starts needed).
The structure is held at the truth. Real SfM also re-optimises the points (bundle adjustment):
they move to reduce the errors the one focal leaves, so a real reconstruction's points are
warped, its reprojection errors smaller than the residuals here, and its world frame is its own
(a similarity away). Here the points pin the frame to the true world: no gauge to align, and
every difference from the truth is in the poses.

The reconstruction's sparse points and tracks come with it, as a COLMAP model's
(`tracks`: Dataset.points, point_errors, observations), for depth from the tracks (loss.depth).

The held-out views stay landmark's (true poses, stored pinhole, neutral look). They are
scorable as they are because the fixed structure puts the reconstruction's frame exactly on the
true world: the true held-out cameras are where the same reconstruction would place photos
taken through the stored pinhole, and their renders are the exact images a model of the stored
camera should give there. A test view re-solved as a zoomed photo would need its zoomed photo as
ground truth, which no pose of the stored pinhole renders (the perspective differs): that would
score the reconstruction's camera error together with the model. `Dataset.true_poses` keeps the
true training poses (scored as pose errors by the evaluation).
"""

import dataclasses

import numpy as np

from nerf_jax.data import lens
from nerf_jax.data.scenes import landmark, simulator

GRID = 32  # matched pixels: a GRID x GRID grid over each photo (every 8th pixel at 256)
ITERATIONS = 30  # Levenberg-Marquardt iterations at most (from the true pose: a few suffice)
STEP_TOLERANCE = 1e-12  # ... stop once the update is this small (radians, scene units)
PASSER_TOLERANCE = 1e-3  # a pixel's depth this share short of the static scene's: a passer-by
SKY = len(landmark.SCENE.objects) - 1  # the enclosure's last object, the sky (garden.enclosure)
MIN_POINTS = 6  # fewer matched points than this: a photo's pose is not determined (an error)
TRACK_EVERY = 4  # the tracks' points (Dataset.points): every 4th point each photo matched
SEEN_TOLERANCE = 0.01  # another photo sees a point where its depth there is within 1% of it
UNHIDDEN_TOLERANCE = 1e-6  # ... and a ray cast to it hits nothing before (a share of its length)


def grid_pixels(height, width, size=GRID):
  """(rows, columns) int64 [M]: a size x size grid of pixels (fewer on a smaller photo), at the
  centres of equal cells, row-major."""
  centres = lambda n: np.unique(((np.arange(min(size, n)) + 0.5) * n / min(size, n)).astype(
      np.int64))
  row, column = np.meshgrid(centres(height), centres(width), indexing="ij")
  return row.reshape(-1), column.reshape(-1)


def pixel_rays(pose, rows, columns, height, width, focal, dist, pixel_center):
  """Rays of pixels (rows, columns) int [M] of a photo through a radial lens, as
  `landmark.photo_rays` makes them: (origins, directions) float64 [M, 3], the directions'
  parameter the z-depth. pose: float [4, 4]; focal: float; dist: (k1, k2)."""
  xy = np.stack([columns + pixel_center - 0.5 * width, rows + pixel_center - 0.5 * height],
                -1) / focal
  if any(dist):
    xy = lens.undistort(xy, (float(dist[0]), float(dist[1]), 0.0, 0.0))
  cam = np.concatenate([xy[:, :1], -xy[:, 1:], -np.ones_like(xy[:, :1])], -1)
  pose = np.asarray(pose, np.float64)
  return np.broadcast_to(pose[:3, 3], cam.shape), cam @ pose[:3, :3].T


def matched_points(depth, pose, focal, dist, pixel_center, near=landmark.NEAR,
                   far=landmark.FAR, size=GRID, subject_only=False):
  """The points one photo matches (module docstring): (points float64 [M, 3], world; pixels
  float64 [M, 2], (column, row) + pixel_center where the photo shows each, the stored pinhole's
  convention; subject bool [M], on the monument).

  depth: float [H, W], the photo's z-depths (passers-by included); pose: float [4, 4], its true
  camera-to-world; focal, dist: its true focal (pixels) and (k1, k2). subject_only: the
  monument's points alone (a reconstruction whose matches are all on the subject; the
  benchmark's comparison, bench/sfm_twin.py)."""
  height, width = depth.shape
  rows, columns = grid_pixels(height, width, size)
  origins, directions = pixel_rays(pose, rows, columns, height, width, focal, dist,
                                   pixel_center)
  t, index, _ = simulator.first_hit(landmark.SCENE.objects, origins, directions, near, far)
  z = np.asarray(depth, np.float64)[rows, columns]
  static = z >= (1.0 - PASSER_TOLERANCE) * t  # float32 depths: equal up to rounding
  keep = static & (index < len(landmark.SUBJECT) if subject_only else index != SKY)
  points = origins[keep] + z[keep, None] * directions[keep]
  pixels = np.stack([columns[keep], rows[keep]], -1) + pixel_center
  return points, pixels.astype(np.float64), index[keep] < len(landmark.SUBJECT)


def project(points, pose, intrinsics):
  """Pixels float64 [M, 2] ((column, row) + pixel_center) and z-depths float64 [M] of world
  points float [M, 3] through a pinhole (fx, fy, cx, cy) at pose float [4, 4]
  (`visual_hull.project`'s convention, pixel centre added)."""
  fx, fy, cx, cy = intrinsics
  pose = np.asarray(pose, np.float64)
  local = (np.asarray(points, np.float64) - pose[:3, 3]) @ pose[:3, :3]
  depth = -local[:, 2]
  return np.stack([cx + fx * local[:, 0] / depth, cy - fy * local[:, 1] / depth], -1), depth


def _skew(v):
  """float64 [..., 3, 3]: the cross-product matrices of v float [..., 3] ([v]x w = v x w)."""
  zero = np.zeros_like(v[..., 0])
  return np.stack([np.stack([zero, -v[..., 2], v[..., 1]], -1),
                   np.stack([v[..., 2], zero, -v[..., 0]], -1),
                   np.stack([-v[..., 1], v[..., 0], zero], -1)], -2)


def _rotation(w):
  """float64 [3, 3], exp([w]x) of a rotation vector w float64 [3] (Rodrigues)."""
  theta = float(np.linalg.norm(w))
  if theta < 1e-12:  # first order: exact to rounding at this size
    return np.eye(3) + _skew(w)
  k = _skew(w / theta)
  return np.eye(3) + np.sin(theta) * k + (1.0 - np.cos(theta)) * k @ k


def _residuals_and_jacobian(points, pixels, pose, intrinsics):
  """(r float64 [2M], J float64 [2M, 6], depths float64 [M]) of the reprojection at `pose`;
  J with respect to (w, c): rotation R exp([w]x) and centre C + c (camera-to-world)."""
  fx, fy, _, _ = intrinsics
  rot = pose[:3, :3]
  local = (points - pose[:3, 3]) @ rot  # p = R^T (X - C)
  depth = -local[:, 2]  # s; the caller keeps every s > 0
  projected, _ = project(points, pose, intrinsics)
  zero = np.zeros_like(depth)
  # d(u, v)/dp for u = cx + fx p_x / s, v = cy - fy p_y / s, s = -p_z: [M, 2, 3]
  d_uv = np.stack([np.stack([fx / depth, zero, fx * local[:, 0] / depth ** 2], -1),
                   np.stack([zero, -fy / depth, -fy * local[:, 1] / depth ** 2], -1)], -2)
  # p' = exp(-[w]x) R^T (X - C - c) = p + [p]x w - R^T c to first order
  d_p = np.concatenate([_skew(local), np.broadcast_to(-rot.T, (len(points), 3, 3))], -1)
  jacobian = (d_uv @ d_p).reshape(-1, 6)
  return (projected - pixels).reshape(-1), jacobian, depth


def _updated(pose, step):
  """pose float64 [4, 4] with its rotation times exp([step[:3]]x) and step[3:] added to its
  centre."""
  out = pose.copy()
  out[:3, :3] = pose[:3, :3] @ _rotation(step[:3])
  out[:3, 3] = pose[:3, 3] + step[3:]
  return out


def solved_pose(points, pixels, start, intrinsics, iterations=ITERATIONS):
  """The camera-to-world float64 [4, 4] whose pinhole `intrinsics` (fx, fy, cx, cy) projects
  world points float [M, 3] nearest their pixels float [M, 2] (least squares,
  Levenberg-Marquardt from `start` float [4, 4]; a step that would put a point behind the
  camera is refused) and the RMS reprojection error there, in pixels (float)."""
  points, pixels = np.asarray(points, np.float64), np.asarray(pixels, np.float64)
  pose, damping = np.asarray(start, np.float64).copy(), 1e-3
  residual, jacobian, _ = _residuals_and_jacobian(points, pixels, pose, intrinsics)
  cost = float(residual @ residual)
  for _ in range(iterations):
    normal = jacobian.T @ jacobian
    gradient = jacobian.T @ residual
    while damping < 1e12:
      # Marquardt's scaling: the damping is relative to each parameter's own curvature.
      step = np.linalg.solve(normal + damping * np.diag(np.diag(normal)), -gradient)
      trial = _updated(pose, step)
      new = _residuals_and_jacobian(points, pixels, trial, intrinsics)
      new_cost = float(new[0] @ new[0])
      if np.all(new[2] > 0) and new_cost <= cost:
        break
      damping *= 10.0
    else:
      break  # no step lowers the cost: a minimum to rounding
    pose, (residual, jacobian, _), cost = trial, new, new_cost
    damping = max(damping / 10.0, 1e-9)
    if np.max(np.abs(step)) < STEP_TOLERANCE:
      break
  return pose, float(np.sqrt(cost / len(points)))


def reprojection_rms(points, pixels, pose, intrinsics):
  """float: the RMS distance in pixels between pixels float [M, 2] and world points float
  [M, 3] projected through the pinhole `intrinsics` at pose float [4, 4] (`project`)."""
  projected, _ = project(points, pose, intrinsics)
  return float(np.sqrt(np.mean(np.sum((projected - pixels) ** 2, -1))))


@dataclasses.dataclass
class Solve:
  """What the twin's reconstruction did, per training photo: poses float64 [N, 4, 4] (solved),
  rms_px float64 [N] (RMS reprojection error at the solution), true_rms_px float64 [N] (at the
  true pose, where the solve starts), num_points int [N] (matched points), subject_share
  float64 [N] (share of them on the monument), points (each photo's matched points)."""
  poses: np.ndarray
  rms_px: np.ndarray
  true_rms_px: np.ndarray
  num_points: np.ndarray
  subject_share: np.ndarray
  points: list  # of float64 [M_k, 3], the points each photo matched


def reconstruct(train, focals, dists, size=GRID, subject_only=False):
  """`Solve` of the training photos `train` (a Dataset as photographed: its depths, its true
  poses in `poses`) taken through focals float [N] and dists (k1, k2) float [N, 2], posed
  through its stored pinhole (size, subject_only: `matched_points`'). ValueError when a photo
  matches fewer than MIN_POINTS points."""
  poses, rms, true_rms, counts, shares, matched = [], [], [], [], [], []
  for k, pose in enumerate(np.asarray(train.poses, np.float64)):
    points, pixels, subject = matched_points(train.depths[k], pose, focals[k], dists[k],
                                             train.pixel_center, train.near, train.far, size,
                                             subject_only)
    if len(points) < MIN_POINTS:
      raise ValueError(f"landmark_sfm: photo {k} matches {len(points)} points")
    solved, error = solved_pose(points, pixels, pose, train.intrinsics)
    poses.append(solved)
    rms.append(error)
    true_rms.append(reprojection_rms(points, pixels, pose, train.intrinsics))
    counts.append(len(points))
    shares.append(float(np.mean(subject)))
    matched.append(points)
  return Solve(np.stack(poses), np.array(rms), np.array(true_rms), np.array(counts),
               np.array(shares), matched)


def photo_pixels(points, pose, focal, dist, width, height):
  """Where a photo taken through a radial lens shows world points float [M, 3]: (pixels float64
  [M, 2], (column, row) + pixel_center as `matched_points`' pixels; z-depths float64 [M]);
  `pixel_rays` inverted (`lens.distort` of the pinhole coordinates). pose: float [4, 4], the
  photo's true camera-to-world; focal: float, pixels; dist: (k1, k2)."""
  pose = np.asarray(pose, np.float64)
  local = (np.asarray(points, np.float64) - pose[:3, 3]) @ pose[:3, :3]
  depth = -local[:, 2]
  safe = np.where(depth > 0, depth, 1.0)  # behind the camera: the caller drops it by `depth`
  xy = np.stack([local[:, 0] / safe, -local[:, 1] / safe], -1)  # lens.py's axes: y down
  xy = lens.distort(xy, (float(dist[0]), float(dist[1]), 0.0, 0.0))
  return xy * focal + np.array([0.5 * width, 0.5 * height]), depth


def _unhidden(points, pose):
  """bool [M]: whether the static scene hides none of the points float [M, 3] from the centre
  of pose float [4, 4] (the ray towards each first hits the scene at it: at t = 1 of the
  un-normalised direction, to rounding)."""
  centre = np.asarray(pose, np.float64)[:3, 3]
  towards = np.asarray(points, np.float64) - centre
  t, _, _ = simulator.first_hit(landmark.SCENE.objects, np.broadcast_to(centre, towards.shape),
                                towards, 0.0, np.inf)
  return t >= 1.0 - UNHIDDEN_TOLERANCE


def tracks(train, solve, focals, dists, every=TRACK_EVERY):
  """The twin's sparse points and their tracks, as a reconstruction's COLMAP model gives them
  (Dataset.points, point_errors, observations): (points float32 [P, 3], errors float32 [P],
  observations int32 [K, 2] (photo, point)).

  The points: every `every`-th point each photo matched (`solve.points`, true positions). A
  photo sees a point where its true camera (focals, dists) puts it inside the photo with the
  photo's depth there (Dataset.depths, passers-by included) within SEEN_TOLERANCE of the
  point's and no part of the scene in front of it (a pixel next to an edge can have the depth
  of a point the edge hides): the photo it came from and every other that shows it. A point's error
  is COLMAP's: the mean over its track of the distance in pixels between where the photo shows
  it and where the twin's camera (`solve.poses`, the stored pinhole) projects it; held at the
  truth, the points keep errors that bundle adjustment would have reduced."""
  points = np.concatenate([p[::every] for p in solve.points])
  height, width = train.height, train.width
  observations, error_sum, count = [], np.zeros(len(points)), np.zeros(len(points))
  for k in range(len(train)):
    shown, depth = photo_pixels(points, train.poses[k], focals[k], dists[k], width, height)
    # Far outside the photo (or behind it) the lens polynomial is huge: clipped before the cast.
    limit = np.clip(np.nan_to_num(shown, nan=-1.0), -1.0, max(width, height) + 1.0)
    column, row = (np.floor(limit - train.pixel_center + 0.5).astype(np.int64)).T
    inside = (depth > 0) & (column >= 0) & (column < width) & (row >= 0) & (row < height)
    there = np.asarray(train.depths[k], np.float64)[np.clip(row, 0, height - 1),
                                                     np.clip(column, 0, width - 1)]
    seen = np.flatnonzero(inside & (np.abs(there - depth) <= SEEN_TOLERANCE * depth))
    seen = seen[_unhidden(points[seen], train.poses[k])]  # not an edge's neighbour
    projected, _ = project(points[seen], solve.poses[k], train.intrinsics)
    error_sum[seen] += np.linalg.norm(projected - shown[seen], axis=-1)
    count[seen] += 1
    observations.append(np.stack([np.full(len(seen), k), seen], -1))
  # Every point is seen by the photo it came from at least: count >= 1.
  return (points.astype(np.float32), (error_sum / np.maximum(count, 1)).astype(np.float32),
          np.concatenate(observations).astype(np.int32))


def posed(train, seed=0, zoom=True, distortion=True, size=GRID):
  """The training photos `train` (landmark's, `landmark.photographed(..., seed, zoom,
  distortion)`) with the poses the shared-focal reconstruction gives (`reconstruct`), their
  true poses in `true_poses`, and its sparse points and tracks (`tracks`: Dataset.points,
  point_errors, observations)."""
  focals, dists = landmark.lenses(len(train), train.focal, seed, zoom, distortion)
  solve = reconstruct(train, focals, dists, size)
  points, errors, observations = tracks(train, solve, focals, dists)
  return dataclasses.replace(train, poses=solve.poses.astype(np.float32),
                             true_poses=np.asarray(train.poses, np.float32), points=points,
                             point_errors=errors, observations=observations)


SCENE = dataclasses.replace(landmark.SCENE, name="landmark_sfm", effects=dataclasses.replace(
    landmark.SCENE.effects, sfm_poses=True))
