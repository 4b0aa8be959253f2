"""Solid convex primitives and their exact ray intersections (numpy float64).

Every shape is a solid: `shape.intersect(origins, directions)` returns the interval of ray
parameters inside it and the outward normal where the ray enters.
  origins, directions: float64 [R, 3]; directions need not be unit (t is in their units);
  t_in, t_out: float64 [R], the ray is inside the shape for t_in <= t <= t_out; a miss is the
    empty interval t_in = inf, t_out = -inf;
  normal: float64 [R, 3], unit outward normal at t_in (arbitrary for a miss or t_in = -inf).
World space is z-up (see `nerf_jax.cameras.rays.pose_spherical`).
"""

import dataclasses

import numpy as np


def dot(a, b):
  """Row-wise dot product of float64 [R, K] arrays -> [R] (einsum: 3x faster than sum(a * b))."""
  return np.einsum("ij,ij->i", a, b)


def _miss_or(hit, t_in, t_out):
  """Replace the interval by the empty one (inf, -inf) where `hit` is false."""
  return np.where(hit, t_in, np.inf), np.where(hit, t_out, -np.inf)


def _slab(lo, hi, origins, directions):
  """Interval inside lo <= x <= hi along one axis. origins, directions: float64 [R].
  Returns t_near, t_far, and the sign of the entry plane's outward normal: float64 [R] each."""
  # A ray parallel to the slab would divide by zero; 1e-30 gives the same +-inf limits.
  d = np.where(directions == 0.0, 1e-30, directions)
  t0, t1 = (lo - origins) / d, (hi - origins) / d
  return np.minimum(t0, t1), np.maximum(t0, t1), -np.sign(d)


@dataclasses.dataclass(frozen=True)
class Sphere:
  center: tuple  # (x, y, z)
  radius: float

  def intersect(self, origins, directions):
    oc = origins - np.asarray(self.center, np.float64)
    a = dot(directions, directions)
    b = dot(oc, directions)
    disc = b * b - a * (dot(oc, oc) - self.radius ** 2)
    root = np.sqrt(np.maximum(disc, 0.0))
    t_in, t_out = _miss_or(disc >= 0.0, (-b - root) / a, (-b + root) / a)
    t_safe = np.where(np.isfinite(t_in), t_in, 0.0)
    normal = (oc + t_safe[:, None] * directions) / self.radius
    return t_in, t_out, normal


@dataclasses.dataclass(frozen=True)
class Box:
  """An axis-aligned box."""
  center: tuple  # (x, y, z)
  size: tuple  # full extents (sx, sy, sz)

  def intersect(self, origins, directions):
    t_in, t_out = np.full(len(origins), -np.inf), np.full(len(origins), np.inf)
    normal = np.zeros_like(origins)
    for axis in range(3):
      lo = self.center[axis] - 0.5 * self.size[axis]
      t_near, t_far, sign = _slab(lo, lo + self.size[axis], origins[:, axis], directions[:, axis])
      later = t_near > t_in
      normal[later] = 0.0
      normal[later, axis] = sign[later]
      t_in, t_out = np.maximum(t_in, t_near), np.minimum(t_out, t_far)
    return (*_miss_or(t_in <= t_out, t_in, t_out), normal)


@dataclasses.dataclass(frozen=True)
class Cylinder:
  """A capped cylinder with a vertical (z) axis."""
  center: tuple  # (x, y, z) of the middle of the axis
  radius: float
  height: float

  def intersect(self, origins, directions):
    oc = origins - np.asarray(self.center, np.float64)
    o2, d2 = oc[:, :2], directions[:, :2]
    a, b = dot(d2, d2), dot(o2, d2)
    c = dot(o2, o2) - self.radius ** 2
    disc = b * b - a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    vertical = a == 0.0  # inside the infinite cylinder for all t, or never
    a = np.where(vertical, 1.0, a)
    side_in = np.where(vertical, -np.inf, (-b - root) / a)
    side_out = np.where(vertical, np.inf, (-b + root) / a)
    side_in, side_out = _miss_or(np.where(vertical, c <= 0.0, disc >= 0.0), side_in, side_out)
    h = 0.5 * self.height
    cap_in, cap_out, sign = _slab(-h, h, oc[:, 2], directions[:, 2])
    t_side = np.where(np.isfinite(side_in), side_in, 0.0)
    side_normal = np.concatenate(
        [(o2 + t_side[:, None] * d2) / self.radius, np.zeros_like(a)[:, None]], -1)
    cap_normal = np.concatenate([np.zeros_like(o2), sign[:, None]], -1)
    normal = np.where((side_in >= cap_in)[:, None], side_normal, cap_normal)
    t_in, t_out = np.maximum(side_in, cap_in), np.minimum(side_out, cap_out)
    return (*_miss_or(t_in <= t_out, t_in, t_out), normal)
