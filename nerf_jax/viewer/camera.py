"""Cameras of the viewer (viser) and of nerf_jax, and the conversion between them.

Ours (rays.py, OpenGL axes): `c2w: float32 [4, 4]` camera-to-world; the camera looks down its
-z axis, +x right, +y up. Viser's (OpenCV axes): a unit quaternion `wxyz: float64 [4]` (w first)
rotating camera to world and a `position: float64 [3]`; the camera looks down +z, +x right, +y
down. The viewer's world is ours times `scale` (positions only; rotations are shared).
`fov`: viser's vertical field of view in radians.
"""

import math

import numpy as np

from nerf_jax.cameras.keyframes import matrix_to_quaternion, quaternion_to_matrix  # noqa: F401

# OpenGL camera axes (x right, y up, z back) -> OpenCV's (x right, y down, z forward).
_FLIP_YZ = np.diag([1.0, -1.0, -1.0])


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
