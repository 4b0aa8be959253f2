"""Camera intrinsics and OpenCV radial-tangential lens distortion (numpy float64).

Names and conventions:
  xy — normalised image coordinates `float64 [..., 2]`: (x right, y down) / z, OpenCV's camera;
  uv — pixel coordinates `float64 [..., 2]` (column, row) in COLMAP's convention: the centre of
    pixel (i, j) is at (i + 0.5, j + 0.5), so uv = (fx x + cx, fy y + cy);
  dist — `(k1, k2, p1, p2)` or `(k1, k2, p1, p2, k3)`: OpenCV's model (nerfstudio's 'OPENCV')
    x' = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²),
    y' = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y,   r² = x² + y².
`nerf_jax.cameras.rays` casts the ray of pixel (i, j) through (i + pixel_center - cx, ...) / f, so a
Dataset built from COLMAP-convention intrinsics stores (fx, fy, cx - 0.5, cy - 0.5): with the
pixel_center = 0 (what such a Dataset records) its rays pass through pixel centres
(`dataset_intrinsics`).
"""

import numpy as np

from nerf_jax.data import resampling

# COLMAP camera models -> the names of their parameters, in order.
COLMAP_PARAMS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
}


def from_colmap(model, params):
  """(fx, fy, cx, cy), (k1, k2, p1, p2) of a COLMAP camera: model str, params float [P]."""
  if model not in COLMAP_PARAMS:
    raise ValueError(f"camera model {model!r} is not supported (supported: "
                     f"{', '.join(COLMAP_PARAMS)})")
  named = dict(zip(COLMAP_PARAMS[model], (float(p) for p in params)))
  fx, fy = named.get("fx", named.get("f")), named.get("fy", named.get("f"))
  dist = tuple(named.get(k, 0.0) for k in ("k1", "k2", "p1", "p2"))
  return (fx, fy, named["cx"], named["cy"]), dist


def distort(xy, dist):
  """Distorted normalised coordinates: float64 [..., 2] -> float64 [..., 2] (see module doc)."""
  k1, k2, p1, p2, k3 = (tuple(dist) + (0.0,))[:5]
  x, y = xy[..., 0], xy[..., 1]
  r2 = x * x + y * y
  radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
  return np.stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                   y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], axis=-1)


def _jacobian(xy, dist):
  """d distort / d xy: float64 [..., 2, 2]."""
  k1, k2, p1, p2, k3 = (tuple(dist) + (0.0,))[:5]
  x, y = xy[..., 0], xy[..., 1]
  r2 = x * x + y * y
  radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
  d_radial = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r², and d r² / dx = 2x
  dxdx = radial + 2 * x * x * d_radial + 2 * p1 * y + 6 * p2 * x
  dxdy = 2 * x * y * d_radial + 2 * p1 * x + 2 * p2 * y
  dydx = 2 * x * y * d_radial + 2 * p1 * x + 2 * p2 * y
  dydy = radial + 2 * y * y * d_radial + 6 * p1 * y + 2 * p2 * x
  return np.stack([np.stack([dxdx, dxdy], -1), np.stack([dydx, dydy], -1)], -2)


def undistort(xy_distorted, dist, iterations=20):
  """Inverse of `distort` by Newton's method from xy = xy_distorted.

  xy_distorted: float64 [..., 2]. Returns float64 [..., 2]. Converges for the distortions of
  real lenses inside the image (where distort is monotonic); points beyond the fold of a strong
  barrel distortion have no inverse and come back wherever Newton stopped.
  """
  target = np.asarray(xy_distorted, np.float64)
  xy = target.copy()
  for _ in range(iterations):
    residual = distort(xy, dist) - target
    jac = _jacobian(xy, dist)
    det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
    det = np.where(np.abs(det) < 1e-12, 1e-12, det)  # past the fold: avoid a division by 0
    step_x = (jac[..., 1, 1] * residual[..., 0] - jac[..., 0, 1] * residual[..., 1]) / det
    step_y = (jac[..., 0, 0] * residual[..., 1] - jac[..., 1, 0] * residual[..., 0]) / det
    xy = xy - np.stack([step_x, step_y], -1)
  return xy


def project(points_cam, intrinsics, dist=(0.0, 0.0, 0.0, 0.0)):
  """Pixel coordinates uv of points in OpenCV camera space (x right, y down, z forward).

  points_cam: float64 [..., 3] with z > 0. intrinsics: (fx, fy, cx, cy), COLMAP convention.
  Returns float64 [..., 2].
  """
  fx, fy, cx, cy = intrinsics
  xy = distort(points_cam[..., :2] / points_cam[..., 2:], dist)
  return xy * np.array([fx, fy]) + np.array([cx, cy])


def resample(image, intrinsics, dist, target_intrinsics, target_size):
  """The photo `image` (taken through intrinsics + dist) as seen by a pinhole camera.

  image: float [H, W, C]. intrinsics, target_intrinsics: (fx, fy, cx, cy), COLMAP convention.
  dist: OpenCV coefficients of `image`'s lens. target_size: (height, width).
  Returns float64 [height, width, C]: pixel (i, j) is `image` at the distorted projection of the
  target pixel centre's ray (bilinear, edges replicated where the ray leaves the photo).
  """
  height, width = target_size
  fx, fy, cx, cy = target_intrinsics
  u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5, indexing="xy")
  rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], -1)
  uv = project(rays, intrinsics, dist)  # pixel centres at +0.5: continuous indices - 0.5
  return resampling.bilinear(np.asarray(image, np.float64), uv[..., 1] - 0.5, uv[..., 0] - 0.5)


def dataset_intrinsics(intrinsics):
  """COLMAP-convention (fx, fy, cx, cy) -> the Dataset's, for pixel_center = 0 (module doc)."""
  fx, fy, cx, cy = intrinsics
  return (float(fx), float(fy), float(cx) - 0.5, float(cy) - 0.5)
