"""Camera paths: the default video path, pose files, and paths through key cameras."""

import json

import numpy as np

from nerf_jax.cameras import keyframes
from nerf_jax.cameras.rays import orbit_poses, spiral_poses


# Key cameras of a capture's smoothed trajectory: at most this many, evenly spread in capture order.
TRAJECTORY_KEYS = 8


def video_poses(dataset, frames, ndc, orbit_phi, orbit_radius, trajectory=False):
  """The camera path of the video: float32 [F, 4, 4].

  Forward-facing data (NDC): a spiral around the mean camera, focused at a depth between the
  bounds (weighted towards near, in disparity, as LLFF does). trajectory (a room, a garden: an
  unbounded scene, where an orbit about the origin would fly through walls): the capture's own
  path, smoothed (`trajectory_poses`). Otherwise: a 360° orbit, the reference's pose_spherical
  path.
  """
  if trajectory:
    return trajectory_poses(dataset.poses, frames)
  if not ndc:
    return orbit_poses(frames, orbit_phi, orbit_radius)
  centre = np.eye(4, dtype=np.float32)
  centre[:3, :] = dataset.poses[:, :3, :].mean(axis=0)
  u, _, vt = np.linalg.svd(centre[:3, :3])
  centre[:3, :3] = u @ vt  # the nearest rotation to the mean rotation
  radii = np.percentile(np.abs(dataset.poses[:, :3, 3] - centre[:3, 3]), 90, axis=0)
  focus = 1.0 / (0.25 / dataset.near + 0.75 / dataset.far)
  return spiral_poses(centre, np.maximum(radii, 1e-3), focus, frames)


def trajectory_poses(poses, frames):
  """float32 [~frames, 4, 4]: a smooth path along the cameras `poses` float [N, 4, 4] in their
  order (a capture's order): through up to TRAJECTORY_KEYS of them, evenly spread, with
  Catmull-Rom positions and slerped rotations (cameras/keyframes.py)."""
  keys = np.asarray(poses, np.float32)[
      np.unique(np.round(np.linspace(0, len(poses) - 1, min(len(poses), TRAJECTORY_KEYS))))
      .astype(int)]
  if len(keys) < 2:
    return np.repeat(keys, max(frames, 1), axis=0)
  return keyframes.interpolate(keys, max(1, frames // (len(keys) - 1)))


def load_poses(path):
  """Camera poses float32 [N, 4, 4] from a .npy ([N,3,4] or [N,4,4]) or a Blender-style .json."""
  if path.endswith(".json"):
    with open(path) as f:
      poses = np.array([frame["transform_matrix"] for frame in json.load(f)["frames"]])
  else:
    poses = np.load(path)
  poses = np.asarray(poses, np.float32)
  if poses.ndim != 3 or poses.shape[1:] not in ((3, 4), (4, 4)):
    raise ValueError(f"{path}: poses must have shape [N, 3, 4] or [N, 4, 4], got {poses.shape}")
  if poses.shape[1] == 3:
    bottom = np.broadcast_to(np.array([0, 0, 0, 1], np.float32), (len(poses), 1, 4))
    poses = np.concatenate([poses, bottom], axis=1)
  return poses


def path_poses(path, frames_per_segment, loop=False):
  """The poses float32 [F, 4, 4] of a camera path through the key cameras in `path`: a .json
  with 'keyframes' (what the viewer saves) or 'frames', or a .npy [K, 3|4, 4] (keyframes.py)."""
  keys = None
  if path.endswith(".json"):
    with open(path) as f:
      keys = json.load(f).get("keyframes")
  keys = load_poses(path) if not keys else np.asarray(keys, np.float32)
  return keyframes.interpolate(keys, frames_per_segment, loop)
