"""Camera paths: key cameras recorded in the viewer, interpolated into a video's poses.

keyframes: float32 [K, 4, 4] camera-to-world (rays.py conventions). Between consecutive key
cameras the rotation turns at a constant rate (quaternion slerp) and the position follows a
Catmull-Rom spline through the key positions, so the path passes through every key camera.
`save_path` writes what `render.py --mode=views --poses=FILE` reads (.json with frames, or .npy).
"""

import json
import os

import numpy as np

from nerf_jax.viewer.camera import matrix_to_quaternion, quaternion_to_matrix


def slerp(q0, q1, u):
  """Quaternion float64 [4] a fraction `u` in [0, 1] of the shorter arc from q0 to q1."""
  q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
  dot = float(np.dot(q0, q1))
  if dot < 0:  # q and -q are one rotation: take the shorter way round
    q1, dot = -q1, -dot
  if dot > 0.9995:  # nearly equal: sin(angle) ≈ 0 below; linear interpolation is exact enough
    q = q0 + u * (q1 - q0)
    return q / np.linalg.norm(q)
  angle = np.arccos(dot)
  return (np.sin((1 - u) * angle) * q0 + np.sin(u * angle) * q1) / np.sin(angle)


def catmull_rom(p0, p1, p2, p3, u):
  """The uniform Catmull-Rom spline between p1 (u=0) and p2 (u=1): float64 [3]."""
  p0, p1, p2, p3 = (np.asarray(p, np.float64) for p in (p0, p1, p2, p3))
  return 0.5 * ((2 * p1) + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u ** 2
                + (-p0 + 3 * p1 - 3 * p2 + p3) * u ** 3)


def interpolate(keyframes, frames_per_segment, loop=False):
  """Poses float32 [F, 4, 4] through `keyframes` float [K, 4, 4] (K >= 2).

  frames_per_segment: int, frames from one key camera to the next (the first of each segment is
  the key camera itself). loop: also return from the last key camera to the first.
  F = frames_per_segment · (K - 1) + 1, or frames_per_segment · K with loop.
  """
  keys = np.asarray(keyframes, np.float64)
  if len(keys) < 2:
    raise ValueError(f"a camera path needs at least 2 key cameras, got {len(keys)}")
  if frames_per_segment < 1:
    raise ValueError(f"frames_per_segment={frames_per_segment}: must be at least 1")
  count = len(keys)
  pos = keys[:, :3, 3]
  quats = [matrix_to_quaternion(k[:3, :3]) for k in keys]
  if loop:
    at = lambda i: pos[i % count]
  else:  # beyond the ends, reflected points: the path leaves the ends at the segment's speed
    ends = {-1: 2 * pos[0] - pos[1], count: 2 * pos[-1] - pos[-2]}
    at = lambda i: ends[i] if i in ends else pos[i]
  poses = []
  for seg in range(count if loop else count - 1):
    for f in range(frames_per_segment):
      u = f / frames_per_segment
      pose = np.eye(4)
      pose[:3, :3] = quaternion_to_matrix(slerp(quats[seg], quats[(seg + 1) % count], u))
      pose[:3, 3] = catmull_rom(at(seg - 1), at(seg), at(seg + 1), at(seg + 2), u)
      poses.append(pose)
  if not loop:
    poses.append(keys[-1])
  return np.stack(poses).astype(np.float32)


def save_path(path, keyframes, poses, fps):
  """Write a camera path: `.json` {'fps', 'keyframes': [...], 'frames': [{'transform_matrix'}]}
  (what camera_paths.load_poses reads), and the poses float32 [F, 4, 4] as `.npy` beside it.

  Returns the paths written.
  """
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  content = {"fps": fps, "keyframes": np.asarray(keyframes).tolist(),
             "frames": [{"transform_matrix": p.tolist()} for p in np.asarray(poses)]}
  with open(path, "w") as f:
    json.dump(content, f)
  npy = os.path.splitext(path)[0] + ".npy"
  np.save(npy, np.asarray(poses, np.float32))
  return [path, npy]
