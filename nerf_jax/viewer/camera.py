"""Cameras of the viewer (viser) and of nerf_jax, and the conversion between them.

Ours (rays.py, OpenGL axes): `c2w: float32 [4, 4]` camera-to-world; the camera looks down its
-z axis, +x right, +y up. Viser's (OpenCV axes): a unit quaternion `wxyz: float64 [4]` (w first)
rotating camera to world and a `position: float64 [3]`; the camera looks down +z, +x right, +y
down. The viewer's world is ours times `scale` (positions only; rotations are shared).
`fov`: viser's vertical field of view in radians.
"""

import math

import numpy as np

# OpenGL camera axes (x right, y up, z back) -> OpenCV's (x right, y down, z forward).
_FLIP_YZ = np.diag([1.0, -1.0, -1.0])


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


def viewer_to_c2w(wxyz, position, scale=1.0):
  """Our camera-to-world float32 [4, 4] of a viser camera (wxyz [4], position [3] in the
  viewer's world, which is ours times `scale`)."""
  c2w = np.eye(4)
  c2w[:3, :3] = quaternion_to_matrix(wxyz) @ _FLIP_YZ
  c2w[:3, 3] = np.asarray(position, np.float64) / scale
  return c2w.astype(np.float32)


def c2w_to_viewer(c2w, scale=1.0):
  """(wxyz float64 [4], position float64 [3]): the viser camera of our c2w float [3|4, 4]."""
  c2w = np.asarray(c2w, np.float64)
  return matrix_to_quaternion(c2w[:3, :3] @ _FLIP_YZ), c2w[:3, 3] * scale


def vertical_fov(height, fy):
  """Vertical field of view in radians of `height` pixels at focal length `fy` pixels."""
  return 2.0 * math.atan(0.5 * height / fy)


def frame_size(height, aspect):
  """(height, width) of a frame `height` pixels tall with the canvas's width/height `aspect`."""
  return int(height), max(1, int(round(height * aspect)))


def frame_intrinsics(height, width, fov):
  """(fx, fy, cx, cy) in pixels of a `height`×`width` frame with vertical `fov` (radians):
  square pixels, principal point at the centre (what the browser's canvas shows)."""
  fy = 0.5 * height / math.tan(0.5 * fov)
  return (fy, fy, 0.5 * width, 0.5 * height)
