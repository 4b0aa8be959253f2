"""Camera pose refinement: a small SE(3) correction per training image, learnt with the field.

xi: float32 [..., 6], a correction: (ω, v), ω the axis-angle rotation (radians) and v the
  translation part of the twist, both in the camera's own frame.
c2w: float32 [..., 4, 4] camera-to-world (rays.py conventions).
The corrected camera is c2w @ exp(xi): it turns about its own centre and moves along its own
axes, so a correction means the same for every camera wherever it stands. A correction of zeros
is the identity exactly (exp(0) = I), so refinement starts from the given poses.

Held-out views are taken by cameras that were not refined. `align_cameras` fits the similarity
transform (Umeyama) that takes the given training cameras to the refined ones, the frame the
field was learnt in, and `transform` applies it to the held-out poses
(evaluation.py); `pose_errors` scores refined cameras against true ones the same way.
"""

import jax.numpy as jnp
import numpy as np

from nerf_jax.backend import precision
from nerf_jax.cameras import rays

SMALL_ANGLE_SQ = 1e-2  # θ² below which the series are used: (θ - sin θ)/θ³ cancels in float32


def hat(w):
  """Cross-product matrices float32 [..., 3, 3] of vectors w float32 [..., 3]: hat(w) @ x =
  w × x."""
  zero = jnp.zeros_like(w[..., 0])
  return jnp.stack([jnp.stack([zero, -w[..., 2], w[..., 1]], -1),
                    jnp.stack([w[..., 2], zero, -w[..., 0]], -1),
                    jnp.stack([-w[..., 1], w[..., 0], zero], -1)], -2)


def se3_exp(xi):
  """The exponential map of se(3): float32 [..., 6] twists -> float32 [..., 4, 4] rigid
  transforms [[R, V v], [0, 1]], R = I + A W + B W², V = I + B W + C W² (W = hat(ω), θ = |ω|,
  A = sin θ/θ, B = (1 - cos θ)/θ², C = (θ - sin θ)/θ³).

  Near θ = 0 the coefficients come from their Taylor series (to θ⁴; the next terms are below
  float32's resolution for θ² < SMALL_ANGLE_SQ), and θ is computed from a clamped θ² on the
  other branch, so the value and the gradient are finite at ω = 0 (sqrt'(0) is infinite).
  """
  w, v = xi[..., :3], xi[..., 3:]
  theta_sq = jnp.sum(w * w, axis=-1)[..., None, None]
  small = theta_sq < SMALL_ANGLE_SQ
  safe_sq = jnp.where(small, 1.0, theta_sq)
  theta = jnp.sqrt(safe_sq)
  a = jnp.where(small, 1.0 - theta_sq / 6.0 + theta_sq ** 2 / 120.0, jnp.sin(theta) / theta)
  b = jnp.where(small, 0.5 - theta_sq / 24.0 + theta_sq ** 2 / 720.0,
                (1.0 - jnp.cos(theta)) / safe_sq)
  c = jnp.where(small, 1.0 / 6.0 - theta_sq / 120.0 + theta_sq ** 2 / 5040.0,
                (theta - jnp.sin(theta)) / (safe_sq * theta))
  big_w = hat(w)
  w_sq = precision.matmul(big_w, big_w)
  eye = jnp.eye(3, dtype=xi.dtype)
  rot = eye + a * big_w + b * w_sq
  trans = precision.matmul(eye + b * big_w + c * w_sq, v[..., None])
  top = jnp.concatenate([rot, trans], axis=-1)
  bottom = jnp.broadcast_to(jnp.array([0.0, 0.0, 0.0, 1.0], xi.dtype), (*xi.shape[:-1], 1, 4))
  return jnp.concatenate([top, bottom], axis=-2)


def corrected(c2w, xi):
  """The corrected cameras c2w @ exp(xi): float32 [..., 4, 4] (module docstring)."""
  return precision.matmul(jnp.asarray(c2w, jnp.float32), se3_exp(xi))


def align(src, dst, with_scale=True):
  """The similarity (s, R, t) minimising Σ |s R src_i + t - dst_i|² (Umeyama 1991).

  src, dst: float [N, 3] corresponding points, N >= 3 not on one line. Returns s float, R
  float64 [3, 3] (a rotation: det +1), t float64 [3]; s = 1 without with_scale.
  """
  src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
  mu_s, mu_d = src.mean(0), dst.mean(0)
  xs, xd = src - mu_s, dst - mu_d
  u, sing, vt = np.linalg.svd(xd.T @ xs / len(src))
  flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
  rot = u @ flip @ vt
  var = np.mean(np.sum(xs * xs, axis=1))
  scale = float(np.trace(np.diag(sing) @ flip) / var) if with_scale and var > 0 else 1.0
  return scale, rot, mu_d - scale * rot @ mu_s


def camera_points(poses):
  """Each camera's centre and the points one scene unit along its x, y and viewing (-z) axes:
  float64 [4N, 3] of cameras float [N, 4, 4]. Aligning these instead of the centres alone
  fixes the rotation even where the centres lie on a line."""
  poses = np.asarray(poses, np.float64)
  centres = poses[:, :3, 3]
  ahead = [centres + sign * poses[:, :3, axis] for axis, sign in ((0, 1), (1, 1), (2, -1))]
  return np.concatenate([centres, *ahead])


def align_cameras(src, dst):
  """The similarity (`align`) taking cameras src to cameras dst (float [N, 4, 4]), fitted to
  their `camera_points`."""
  return align(camera_points(src), camera_points(dst))


def transform(poses, similarity):
  """Cameras float [..., 4, 4] moved by `similarity` (s, R, t) of `align`: centres c -> s R c
  + t, orientations R_c -> R R_c. Returns float64 [..., 4, 4]."""
  scale, rot, trans = similarity
  out = np.array(poses, np.float64)
  out[..., :3, :3] = rot @ out[..., :3, :3]
  out[..., :3, 3] = scale * out[..., :3, 3] @ rot.T + trans
  return out


def rotation_degrees(rot_a, rot_b):
  """Angles in degrees float64 [...] of the rotations taking rot_a to rot_b (float [..., 3, 3])."""
  rel = np.swapaxes(np.asarray(rot_a, np.float64), -1, -2) @ np.asarray(rot_b, np.float64)
  # atan2 of sine and cosine: arccos of the cosine alone loses half the digits near 0.
  cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
  skew = rel - np.swapaxes(rel, -1, -2)
  sin = 0.5 * np.linalg.norm(np.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], -1),
                             axis=-1)
  return np.degrees(np.arctan2(sin, cos))


def pose_errors(poses, true_poses, surface=None):
  """How far cameras `poses` are from `true_poses` (float [N, 4, 4]) once the frame they share
  is aligned (`align_cameras`, with scale): {'degrees': mean angle of the rotations,
  'translation': mean centre distance, in the true poses' units}. With `surface` (depths,
  accs, intrinsics: the true views' z-depth and opacity float [N, H, W] and (fx, fy, cx, cy))
  also 'reprojection_px' (`reprojection_px`)."""
  moved = transform(poses, align_cameras(poses, true_poses))
  true_poses = np.asarray(true_poses, np.float64)
  errors = {"degrees": float(np.mean(rotation_degrees(moved[:, :3, :3],
                                                      true_poses[:, :3, :3]))),
            "translation": float(np.mean(np.linalg.norm(moved[:, :3, 3] - true_poses[:, :3, 3],
                                                        axis=-1)))}
  if surface is not None:
    errors["reprojection_px"] = reprojection_px(moved, true_poses, *surface)
  return errors


REPROJECTION_POINTS = 4096  # surface points per view (a strided subset of its opaque pixels)
OPAQUE = 0.99  # true opacity of the pixels whose surface points are reprojected


def reprojection_px(poses, true_poses, depths, accs, intrinsics):
  """The mean distance in pixels between where the true cameras see the visible surface and
  where the cameras `poses` (aligned to the true ones' frame) put it: the error a renderer
  sees. A small turn and a sideways move shift a distant surface alike, so the angle alone
  overstates an error the images cannot tell apart.

  poses, true_poses: float [N, 4, 4]; depths, accs: float [N, H, W] true z-depth and opacity of
  the true views; intrinsics (fx, fy, cx, cy). Surface points: up to REPROJECTION_POINTS pixels
  a view with opacity > OPAQUE, at their true depth."""
  fx, fy = intrinsics[:2]
  directions = rays.pixel_directions(depths.shape[1], depths.shape[2], *intrinsics, 0.5)
  camera_xy = np.asarray(directions, np.float64)[..., :2]  # z = -1: x/-z and y/-z
  means = []
  for pose, true, depth, acc in zip(np.asarray(poses, np.float64), true_poses, depths, accs):
    pick = np.flatnonzero(acc.reshape(-1) > OPAQUE)
    pick = pick[::max(1, len(pick) // REPROJECTION_POINTS)]
    if not len(pick):
      continue
    z = depth.reshape(-1)[pick, None]
    local = np.concatenate([camera_xy.reshape(-1, 2)[pick] * z, -z], -1)
    world = local @ true[:3, :3].T + true[:3, 3]
    seen = (world - pose[:3, 3]) @ pose[:3, :3]  # into the camera `pose`: R^T (X - t)
    shift = seen[:, :2] / -seen[:, 2:] - camera_xy.reshape(-1, 2)[pick]
    means.append(np.mean(np.hypot(fx * shift[:, 0], fy * shift[:, 1])))
  return float(np.mean(means)) if means else float("nan")
