"""Key cameras (recorded in the viewer) interpolated into a video's poses; rotations as quaternions.

keyframes: float32 [K, 4, 4] camera-to-world (rays.py conventions). Between consecutive key
cameras the rotation turns at a constant rate (quaternion slerp) and the position follows a
Catmull-Rom spline through the key positions, so the path passes through every key camera.
`save_path` writes what `render.py --mode=views --poses=FILE` reads (.json with frames, or .npy).
"""

import json
import math
import os

import numpy as np



def quaternion_to_matrix(wxyz):
  """Rotation float64 [3, 3] of a quaternion float [4] (w, x, y, z; normalised here)."""
  w, x, y, z = np.asarray(wxyz, np.float64) / np.linalg.norm(wxyz)
  return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                   [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                   [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def matrix_to_quaternion(rotation):
  """Unit quaternion float64 [4] (w, x, y, z; w >= 0) of a rotation float [3, 3].

  Shepperd's method: divides by the largest of the four candidate magnitudes, so it stays
  accurate near 180° turns, where dividing by w (≈ 0) would not.
  """
  r = np.asarray(rotation, np.float64)
  trace = np.trace(r)
  candidates = [trace, r[0, 0], r[1, 1], r[2, 2]]
  k = int(np.argmax(candidates))
  if k == 0:
    s = 2.0 * math.sqrt(1.0 + trace)
    q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
  else:
    i, j, l = k - 1, k % 3, (k + 1) % 3
    s = 2.0 * math.sqrt(1.0 + r[i, i] - r[j, j] - r[l, l])
    q = np.zeros(4)
    q[0] = (r[l, j] - r[j, l]) / s
    q[1 + i] = 0.25 * s
    q[1 + j] = (r[j, i] + r[i, j]) / s
    q[1 + l] = (r[l, i] + r[i, l]) / s
  q = np.asarray(q, np.float64)
  return q if q[0] >= 0 else -q


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
