"""A noise-textured scene photographed by known cameras through a real (OpenCV) lens: the
ground truth of the capture pipeline's tests and benchmark (`nerf_jax.data.process`).

Three solids on a slab, every surface painted with 3-D value noise (SIFT needs texture; the
flat-coloured built-in scenes give it nothing to match), lit by the simulator's Lambertian
model, black background. Pixels follow COLMAP's convention (pixel k's centre at k + 0.5) and the
lens is inverted here by its own fixed-point iteration, independently of `nerf_jax.data.lens`.
"""

import numpy as np

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data.scenes import Box, Cylinder, Light, Sphere, simulator

SHAPES = (Sphere((0.0, 0.0, 0.05), 0.45), Box((0.55, -0.4, -0.15), (0.4, 0.4, 0.6)),
          Cylinder((-0.45, 0.5, -0.15), 0.3, 0.6), Box((0.0, 0.0, -0.55), (2.0, 2.0, 0.2)))
LIGHT = Light(direction=(0.4, -0.3, 0.85), color=(0.75, 0.75, 0.75), ambient=(0.3, 0.3, 0.3))


def _value_noise(points, lattice, frequency):
  """Trilinear value noise. points: float64 [R, 3]; lattice: float64 [L, L, L, 3] random
  colours, tiled. Returns float64 [R, 3]."""
  size = lattice.shape[0]
  p = points * frequency
  base = np.floor(p).astype(np.int64)
  f = p - base
  out = np.zeros((len(points), 3))
  for corner in np.ndindex(2, 2, 2):
    idx = (base + corner) % size
    w = np.prod(np.where(corner, f, 1.0 - f), axis=-1)
    out += w[:, None] * lattice[idx[:, 0], idx[:, 1], idx[:, 2]]
  return out


def albedo(points, octaves=3, seed=0):
  """Noise texture of 1 to 3 octaves (1: smooth): float64 [R, 3] in [0.05, 0.95]."""
  rng = np.random.default_rng(seed)
  total = np.zeros((len(points), 3))
  bands = ((5.0, 0.3), (12.0, 0.35), (26.0, 0.35))[:octaves]
  for k, (freq, amp) in enumerate(bands):
    total += amp * _value_noise(points + 0.37 * k, rng.uniform(0, 1, (32, 32, 32, 3)), freq)
  total /= sum(amp for _, amp in bands)
  return np.clip(0.5 + 2.5 * (total - 0.5), 0.05, 0.95)


def render(c2w, height, width, intrinsics, dist=None, octaves=3, near=0.5, far=20.0):
  """One photograph: float32 [H, W, 3] in [0, 1] (black background).

  c2w: float [4, 4] (`nerf_jax.cameras.rays` conventions). intrinsics: (fx, fy, cx, cy) in COLMAP's
  pixel convention (pixel k's centre at k + 0.5). dist: None or (k1, k2, p1, p2): the photo is
  octaves: texture detail (`albedo`). The photo is
  taken through that OpenCV lens (each pixel centre is undistorted by fixed-point iteration,
  independently of `nerf_jax.data.lens`).
  """
  fx, fy, cx, cy = intrinsics
  u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5, indexing="xy")
  xd, yd = (u - cx) / fx, (v - cy) / fy
  x, y = xd.copy(), yd.copy()
  if dist is not None:
    k1, k2, p1, p2 = dist
    for _ in range(100):  # OpenCV's undistortPoints iteration
      r2 = x * x + y * y
      radial = 1 + k1 * r2 + k2 * r2 * r2
      x = (xd - 2 * p1 * x * y - p2 * (r2 + 2 * x * x)) / radial
      y = (yd - p1 * (r2 + 2 * y * y) - 2 * p2 * x * y) / radial
  dirs = np.stack([x, -y, -np.ones_like(x)], -1).reshape(-1, 3)  # OpenCV y down -> ours y up
  origins, directions = rays_lib.to_world(dirs, np.asarray(c2w, np.float32))
  return render_rays(origins, directions, octaves, near, far).reshape(height, width, 3)


def render_rays(origins, directions, octaves=3, near=0.5, far=20.0):
  """Colours of rays: origins, directions float [..., 3] -> float32 [R, 3] (flattened)."""
  origins = np.asarray(origins, np.float64).reshape(-1, 3)
  directions = np.asarray(directions, np.float64).reshape(-1, 3)
  objects = tuple(_Solid(s) for s in SHAPES)
  t, index, normal = simulator.first_hit(objects, origins, directions, near, far)
  hit = np.isfinite(t)
  rgb = np.zeros_like(origins)
  points = origins[hit] + t[hit, None] * directions[hit]
  rgb[hit] = simulator.diffuse(albedo(points, octaves), normal[hit], LIGHT, np.ones(hit.sum()))
  return np.clip(rgb, 0, 1).astype(np.float32)


class _Solid:
  """`simulator.first_hit` wants objects with a `shape`."""

  def __init__(self, shape):
    self.shape = shape


def ring_poses(num_views, radius=3.2, seed=0):
  """Cameras around the scene looking at the origin: float32 [N, 4, 4], azimuth evenly spread
  (jittered), elevation between 20° and 45° above the horizon."""
  rng = np.random.default_rng(seed)
  thetas = np.linspace(0, 360, num_views, endpoint=False) + rng.uniform(-5, 5, num_views)
  phis = -rng.uniform(20, 45, num_views)
  return np.stack([rays_lib.pose_spherical(t, p, radius) for t, p in zip(thetas, phis)])
