"""Cameras and rays.

Conventions (those of the tiny_nerf data and the Keras reference):
  * camera-to-world matrices `c2w: float32 [3, 4] or [4, 4]`; the camera looks down its -z axis,
    +x is right and +y is up in the image;
  * pixel (i, j) = (column, row) looks along `c2w[:3, :3] @ [(i + p - cx)/fx, -(j + p - cy)/fy, -1]`
    where p is the pixel-centre offset (0 = pixel corners as in the reference, 0.5 = pixel centres
    as in Blender or Mitsuba);
  * ray directions are NOT normalised: their camera-space z component is -1, so the distance `t`
    along a ray is the depth along the optical axis (z-depth). near/far bounds are z-planes.
"""

import math
from typing import Optional

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.backend import precision
from nerf_jax.cameras import ndc


# A uniform square pixel of side dx has per-axis variance dx^2/12; a uniform disc of radius r
# has r^2/4. The disc with the pixel's variance has r = dx·2/sqrt(12) (mip-NeRF, section 3.1).
PIXEL_TO_RADIUS = 2.0 / math.sqrt(12.0)


@flax.struct.dataclass
class Rays:
  """A batch of rays: everything the renderer needs per ray (a pytree; leading shape `...`).

  origins: float32 [..., 3], where each ray starts (world space, or NDC for forward scenes).
  directions: float32 [..., 3], un-normalised direction (camera-space z = -1), so t is z-depth.
  viewdirs: float32 [..., 3], unit world viewing direction (what the view branch sees; in NDC
    it is not the direction of the NDC ray).
  near, far: float32 [...], the interval of t to sample.
  image: int32 [...] or None, the training image each ray comes from (per-ray conditioning:
    its appearance code, multinerf's cam_idx); None = no image (held-out views: the mean code).
  radii: float32 [...] or None, each ray's base radius: its pixel's cone has radius radii·t at
    t (cameras/cones.py; mip-NeRF's dx·2/√12); None = thin rays (filled only when asked:
    `pixel_rays(..., with_radii=True)`, for encodings of cones).
  """
  origins: jnp.ndarray
  directions: jnp.ndarray
  viewdirs: jnp.ndarray
  near: jnp.ndarray
  far: jnp.ndarray
  image: Optional[jnp.ndarray] = None
  radii: Optional[jnp.ndarray] = None

  @classmethod
  def create(cls, origins, directions, near, far, viewdirs=None):
    """Rays with `near`, `far` broadcast to the batch shape; viewdirs None = unit directions."""
    origins, directions = jnp.asarray(origins, jnp.float32), jnp.asarray(directions, jnp.float32)
    viewdirs = safe_normalize(directions) if viewdirs is None else jnp.asarray(viewdirs,
                                                                               jnp.float32)
    full = lambda v: jnp.broadcast_to(jnp.asarray(v, jnp.float32), origins.shape[:-1])
    return cls(origins, directions, viewdirs, full(near), full(far))

  @property
  def shape(self):
    """The batch shape `...`."""
    return self.origins.shape[:-1]

  def reshape(self, *shape):
    """The same rays with batch shape `shape`."""
    return jax.tree_util.tree_map(lambda a: a.reshape(*shape, *a.shape[len(self.shape):]), self)


def safe_normalize(v, eps=1e-20):
  """Unit vectors with a finite value and gradient at v = 0.

  v: float32 [..., 3]. Returns float32 [..., 3]; the zero vector maps to zero.
  A plain v / |v| divides by zero at the origin, and the gradient of sqrt(0) is inf; clamping the
  squared norm *before* the sqrt keeps both the value and the gradient finite.
  """
  sq_norm = jnp.sum(v * v, axis=-1, keepdims=True)
  return v * jnp.reciprocal(jnp.sqrt(jnp.maximum(sq_norm, eps)))


def pixel_directions(height, width, fx, fy, cx, cy, pixel_center=0.0):
  """Camera-space directions of every pixel.

  height, width: int, image size. fx, fy: float focal lengths in pixels. cx, cy: float principal
  point in pixels. pixel_center: float offset inside a pixel (0 corners, 0.5 centres).
  Returns float32 [height, width, 3] with z = -1.
  """
  i, j = jnp.meshgrid(jnp.arange(width, dtype=jnp.float32),
                      jnp.arange(height, dtype=jnp.float32), indexing="xy")
  return _directions(i, j, fx, fy, cx, cy, pixel_center)


def _directions(i, j, fx, fy, cx, cy, pixel_center):
  """Camera-space directions float32 [..., 3] (z = -1) of pixels at column i, row j [...]."""
  x = (i + pixel_center - cx) / fx
  y = -(j + pixel_center - cy) / fy
  return jnp.stack([x, y, -jnp.ones_like(x)], axis=-1)


def to_world(dirs_cam, c2w):
  """World-space rays from camera-space directions.

  dirs_cam: float32 [..., 3]. c2w: float32 [3, 4] or [4, 4]. Returns (origins, directions), each
  float32 [..., 3].
  """
  c2w = jnp.asarray(c2w, jnp.float32)
  # Full float32 (precision.py): a TF32 turn is off by ~0.3 px at 400 px.
  directions = precision.einsum("ij,...j->...i", c2w[:3, :3], dirs_cam)
  origins = jnp.broadcast_to(c2w[:3, 3], directions.shape)
  return origins, directions


def get_rays(height, width, focal, c2w, pixel_center=0.0):
  """Rays through every pixel of a pinhole camera with a centred principal point.

  height, width: int. focal: float, focal length in pixels. c2w: float32 [3, 4] or [4, 4].
  pixel_center: float, 0 (reference, default) or 0.5.
  Returns (origins, directions): each float32 [height, width, 3].
  """
  dirs = pixel_directions(height, width, focal, focal, width * 0.5, height * 0.5, pixel_center)
  return to_world(dirs, c2w)


def get_rays_intrinsics(height, width, intrinsics, c2w, pixel_center=0.0):
  """Like `get_rays` with general intrinsics `(fx, fy, cx, cy)` in pixels."""
  fx, fy, cx, cy = intrinsics
  return to_world(pixel_directions(height, width, fx, fy, cx, cy, pixel_center), c2w)


def camera_rays(height, width, intrinsics, c2w, near, far, pixel_center=0.5, use_ndc=False,
                with_radii=False):
  """The `Rays` through every pixel of one camera, as the renderer queries the field.

  intrinsics: (fx, fy, cx, cy) in pixels. c2w: float32 [3, 4] or [4, 4]. near, far: float.
  use_ndc: map the rays to normalized device coordinates (forward-facing scenes, see ndc.py;
  the reference camera's focal is this camera's, and near/far should then be 0 and 1).
  with_radii: fill Rays.radii (`pixel_rays`).
  Returns Rays with batch shape [height, width]; viewdirs are the unit world directions.
  """
  i, j = jnp.meshgrid(jnp.arange(width, dtype=jnp.float32),
                      jnp.arange(height, dtype=jnp.float32), indexing="xy")
  return pixel_rays(i, j, height, width, intrinsics, c2w, near, far, pixel_center, use_ndc,
                    with_radii)


def base_radius(fx, fy):
  """The base radius of every ray of a pinhole camera: its pixels' footprint at t = 1.

  fx, fy: float or float32 [...] (e.g. one per image), focal lengths in pixels, > 0.
  Returns float32 [...]: PIXEL_TO_RADIUS · sqrt(dx·dy), dx = 1/fx and dy = 1/fy the distances
  between neighbouring pixels' directions (they lie in the plane z = -1, so the distance is the
  same for every pixel). mip-NeRF uses one neighbour's distance (dx, for its square pixels);
  for non-square pixels the geometric mean keeps the footprint's area (the disc's variance
  matches the pixel's in area, i.e. in the determinant of the covariance). Equal to mip-NeRF's
  for fx = fy.
  """
  fx, fy = jnp.asarray(fx, jnp.float32), jnp.asarray(fy, jnp.float32)
  # sqrt(fx)·sqrt(fy) rather than sqrt(fx·fy): no overflow for any positive float32 focal.
  return PIXEL_TO_RADIUS / (jnp.sqrt(fx) * jnp.sqrt(fy))


def pixel_rays(i, j, height, width, intrinsics, c2w, near, far, pixel_center=0.5,
               use_ndc=False, with_radii=False, lens=None):
  """`camera_rays` of the pixels at column i, row j (float32 [...]) of a height×width camera.

  The batch shape is that of i and j, not the image's, so a jitted caller working through an
  image in fixed-size pieces compiles once for every image size. height, width: int (NDC only).
  with_radii: fill Rays.radii, each pixel's base radius: base_radius(fx, fy) (the same for
  every pixel of a pinhole camera); in NDC mip-NeRF's, PIXEL_TO_RADIUS times the distance
  between the NDC directions of the pixel and of the one below it (row j + 1; mip-NeRF takes
  the row above for its last row).
  lens: None (the pinhole `intrinsics`), or a refined camera (intrinsics_refinement.Lens, over
  the batch shape): its `undistort` moves the pinhole's camera-space directions and scales the
  base radius; NDC keeps the stored focal (the warp is the scene's, one for every camera).
  """
  fx, fy, cx, cy = intrinsics

  def camera_dirs(j):  # (camera-space directions [..., 3], radius scale [...] or None)
    dirs = _directions(i, j, fx, fy, cx, cy, pixel_center)
    return (dirs, None) if lens is None else lens.undistort(dirs)
  dirs, radius_scale = camera_dirs(j)
  origins, directions = to_world(dirs, c2w)
  viewdirs = safe_normalize(directions)
  if use_ndc:
    to_ndc = lambda o, d: ndc.ndc_rays(o, d, fx, width, height, near=1.0, focal_y=fy)
    if with_radii:
      _, below = to_ndc(*to_world(camera_dirs(j + 1.0)[0], c2w))
    origins, directions = to_ndc(origins, directions)
  rays = Rays.create(origins, directions, near, far, viewdirs)
  if not with_radii:
    return rays
  if use_ndc:
    radii = PIXEL_TO_RADIUS * jnp.sqrt(jnp.sum((below - directions) ** 2, axis=-1))
  else:
    radii = base_radius(fx, fy) if lens is None else base_radius(fx, fy) * radius_scale
    radii = jnp.broadcast_to(radii, rays.shape)
  return rays.replace(radii=radii)


def ray_box_bounds(origins, directions, bound, near, far):
  """Per-ray [t_min, t_max] of the part of [near, far] inside the box [-bound, bound]^3.

  origins, directions: float32 [..., 3]. near, far: float or float32 [...]. Returns (t_min,
  t_max), each float32 [...], with t_min <= t_max; a ray that misses the box gets t_min = t_max
  (a zero-length segment, which composites to nothing). Slab method; a zero direction component
  divides by a tiny signed number instead of 0, so the slab bounds become ±huge (the ray is
  parallel to that slab).
  """
  safe = jnp.where(jnp.abs(directions) < 1e-12, jnp.where(directions < 0, -1e-12, 1e-12),
                   directions)
  t1 = (-bound - origins) / safe
  t2 = (bound - origins) / safe
  t_enter = jnp.max(jnp.minimum(t1, t2), axis=-1)
  t_exit = jnp.min(jnp.maximum(t1, t2), axis=-1)
  t_min = jnp.clip(t_enter, near, far)
  t_max = jnp.clip(t_exit, near, far)
  return t_min, jnp.maximum(t_min, t_max)


def project(points, height, width, focal, c2w, pixel_center=0.0):
  """Inverse of `get_rays`: the continuous pixel coordinates (i, j) of world points.

  points: float [..., 3]. Returns float [..., 2] (column i, row j) such that the ray of pixel
  (i, j) passes through the point.
  """
  c2w = np.asarray(c2w, np.float64)
  rot, origin = c2w[:3, :3], c2w[:3, 3]
  cam = (np.asarray(points, np.float64) - origin) @ rot  # world -> camera: R^T (p - o)
  x, y = cam[..., 0] / -cam[..., 2], cam[..., 1] / -cam[..., 2]
  return np.stack([x * focal + width * 0.5 - pixel_center,
                   -y * focal + height * 0.5 - pixel_center], axis=-1)


def pose_spherical(theta, phi, radius):
  """Camera-to-world matrix on a sphere, looking at the origin (the reference's orbit).

  theta: float, azimuth in degrees. phi: float, elevation in degrees (negative = above the
  horizon, looking down). radius: float, distance to the origin. Returns float32 [4, 4].
  """
  th, ph = math.radians(theta), math.radians(phi)
  translate = np.eye(4)
  translate[2, 3] = radius
  rot_phi = np.array([[1, 0, 0, 0],
                      [0, math.cos(ph), -math.sin(ph), 0],
                      [0, math.sin(ph), math.cos(ph), 0],
                      [0, 0, 0, 1]])
  rot_theta = np.array([[math.cos(th), 0, -math.sin(th), 0],
                        [0, 1, 0, 0],
                        [math.sin(th), 0, math.cos(th), 0],
                        [0, 0, 0, 1]])
  swap = np.array([[-1, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])  # y-up -> z-up
  return (swap @ rot_theta @ rot_phi @ translate).astype(np.float32)


def orbit_poses(num_frames=120, phi=-30.0, radius=4.0):
  """A 360° orbit of `num_frames` poses: float32 [num_frames, 4, 4]."""
  thetas = np.linspace(0.0, 360.0, num_frames, endpoint=False)
  return np.stack([pose_spherical(th, phi, radius) for th in thetas])


def spiral_poses(center_pose, radii, focus_depth, num_frames=120, rotations=2):
  """A spiral path for forward-facing scenes, looking at a point `focus_depth` ahead.

  center_pose: float [3, 4] or [4, 4], the average camera. radii: float [3], spiral extent along
  the camera's x, y, z. Returns float32 [num_frames, 4, 4].
  """
  c2w = np.asarray(center_pose, np.float64)[:3, :4]
  focus = c2w[:, 3] - focus_depth * c2w[:, 2]  # the camera looks down -z
  up = c2w[:, 1]
  poses = []
  for angle in np.linspace(0.0, 2 * np.pi * rotations, num_frames, endpoint=False):
    offset = np.array([math.cos(angle), -math.sin(angle), -math.sin(0.5 * angle)]) * radii
    centre = c2w[:, 3] + c2w[:, :3] @ offset
    back = centre - focus
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, :4] = np.stack([right, np.cross(back, right), back, centre], axis=1)
    poses.append(pose)
  return np.stack(poses).astype(np.float32)
