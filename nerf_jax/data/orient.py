"""Re-orient and scale a capture so that it fits the scene box: z up, the content in [-1, 1]^3.

A capture comes in the arbitrary frame and units of structure from motion. `normalize` finds
  * up: the normal of the plane through the camera centres (cameras circle the subject), or the
    cameras' mean up vector when the centres do not span a plane tilted less than 45° from it;
  * centre and scale: the 2nd-98th percentile box of the sparse points along each new axis
    (robust to stray points) becomes [-1, 1]^3 on its longest side, so `data.scene_bound = 1.5`
    (configs/fast.py) holds it with a margin.
Without points the centre is the point nearest all optical axes and the cameras end up at a mean
distance of 4 (the built-in scenes' rig).

poses: float [N, 4, 4] camera-to-world, OpenGL axes (`nerf_jax.cameras.rays`); points: float [P, 3];
transform: float64 [4, 4], a similarity x -> s R x + t.
"""

import numpy as np

PERCENTILE = 2.0  # the box spans the [2, 98] percentiles of the points on each axis
CAMERA_DISTANCE = 4.0  # mean camera distance when there are no points to measure the subject
BOX_PERCENTILE = 1.0  # `points_box` spans the [1, 99] percentiles of the points on each axis ...
BOX_PADDING = 0.1  # ... widened by this fraction of its size on each side


def _rotation_between(a, b):
  """The smallest rotation taking unit vector a to unit vector b: float64 [3, 3]."""
  v, c = np.cross(a, b), float(np.dot(a, b))
  if c < -1.0 + 1e-9:  # opposite vectors: any half turn about an axis normal to a
    axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    return 2.0 * np.outer(axis, axis) - np.eye(3)
  skew = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
  return np.eye(3) + skew + skew @ skew / (1.0 + c)


def up_direction(poses):
  """The capture's up: float64 [3] unit vector (module docstring)."""
  poses = np.asarray(poses, np.float64)
  mean_up = poses[:, :3, 1].sum(0)
  mean_up /= np.linalg.norm(mean_up)
  centres = poses[:, :3, 3]
  if len(centres) < 3:
    return mean_up
  _, sing, vt = np.linalg.svd(centres - centres.mean(0))
  normal = vt[2] * np.sign(np.dot(vt[2], mean_up) or 1.0)
  planar = sing[1] > 3.0 * sing[2]  # the centres spread in two directions, thin in the third
  return normal if planar and np.dot(normal, mean_up) > np.cos(np.radians(45)) else mean_up


def _focus_point(poses):
  """The point nearest to every optical axis (least squares): float64 [3]."""
  origins, axes = poses[:, :3, 3], -poses[:, :3, 2]
  projector = np.eye(3) - axes[:, :, None] * axes[:, None, :]
  return np.linalg.lstsq(projector.sum(0), np.einsum("nij,nj->i", projector, origins),
                         rcond=None)[0]


def normalize(poses, points=None):
  """The similarity that puts the capture upright in the scene box: float64 [4, 4]."""
  poses = np.asarray(poses, np.float64)
  rot = _rotation_between(up_direction(poses), np.array([0.0, 0.0, 1.0]))
  if points is not None and len(points) >= 4:
    rotated = np.asarray(points, np.float64) @ rot.T
    lo, hi = np.percentile(rotated, [PERCENTILE, 100 - PERCENTILE], axis=0)
    centre, scale = 0.5 * (lo + hi), 2.0 / max(float(np.max(hi - lo)), 1e-12)  # 0 if 1 point
  else:
    centre = rot @ _focus_point(poses)
    distance = np.linalg.norm(poses[:, :3, 3] @ rot.T - centre, axis=-1).mean()
    scale = CAMERA_DISTANCE / max(float(distance), 1e-12)  # all cameras at one point: no scale
  transform = np.eye(4)
  transform[:3, :3] = scale * rot
  transform[:3, 3] = -scale * centre
  return transform


def apply(transform, poses=None, points=None):
  """(poses float32 [N, 4, 4], points float64 [P, 3]) in the new frame; None stays None.
  The rotation part of each pose stays orthonormal: the scale moves only the centres."""
  scale = np.cbrt(np.linalg.det(transform[:3, :3]))
  rot = transform[:3, :3] / scale
  new_poses = None
  if poses is not None:
    poses = np.asarray(poses, np.float64)
    new_poses = np.tile(np.eye(4), (len(poses), 1, 1))
    new_poses[:, :3, :3] = rot @ poses[:, :3, :3]
    new_poses[:, :3, 3] = poses[:, :3, 3] @ transform[:3, :3].T + transform[:3, 3]
    new_poses = new_poses.astype(np.float32)
  new_points = None if points is None else (
      np.asarray(points, np.float64) @ transform[:3, :3].T + transform[:3, 3])
  return new_poses, new_points


def points_box(points):
  """A robust box around `points` (float [P, 3]): float64 [2, 3] (min, max corner), the
  BOX_PERCENTILE-th to (100 - BOX_PERCENTILE)-th percentiles on each axis padded by BOX_PADDING
  of its size; None for fewer than 4 points."""
  if points is None or len(points) < 4:
    return None
  lo, hi = np.percentile(points, [BOX_PERCENTILE, 100 - BOX_PERCENTILE], axis=0)
  pad = BOX_PADDING * (hi - lo)
  return np.stack([lo - pad, hi + pad])


def carry_box(transform, box):
  """The axis-aligned box holding `box` (float [2, 3]) carried by `transform` (float [4, 4]):
  float64 [2, 3]. A rotation makes it larger than the box it carries."""
  corners = np.stack(np.meshgrid(*np.asarray(box).T, indexing="ij"), -1).reshape(-1, 3)
  moved = corners @ transform[:3, :3].T + transform[:3, 3]
  return np.stack([moved.min(0), moved.max(0)])


def depth_bounds(poses, points):
  """(near, far) z-depths that hold what the cameras see: 0.8x the 1st percentile and 1.2x the
  99th of the points' depths in front of each camera; from the box [-1, 1]^3 without points."""
  poses = np.asarray(poses, np.float64)
  if points is None or len(points) < 4:
    distance = np.linalg.norm(poses[:, :3, 3], axis=-1)
    return float(max(distance.min() - np.sqrt(3.0), 0.05)), float(distance.max() + np.sqrt(3.0))
  rel = np.asarray(points)[None] - poses[:, None, :3, 3]
  depth = -np.einsum("npi,ni->np", rel, poses[:, :3, 2]).ravel()  # cameras look down -z
  depth = depth[depth > 0]
  lo, hi = np.percentile(depth, [1.0, 99.0])
  return float(0.8 * lo), float(1.2 * hi)


def orbit(poses):
  """(radius, phi) of `nerf_jax.cameras.rays.orbit_poses` matching the cameras: their median distance
  to the origin and median elevation (negative = above the horizon, as `pose_spherical`)."""
  centres = np.asarray(poses, np.float64)[:, :3, 3]
  radius = np.linalg.norm(centres, axis=-1)
  elevation = np.degrees(np.arcsin(np.clip(centres[:, 2] / np.maximum(radius, 1e-12), -1, 1)))
  return float(np.median(radius)), float(-np.median(elevation))
