"""`landmark`: a tourist photo collection of a monument on a square, with exact ground truth.

What the photos of a real landmark hold and the other built-in scenes lack, all of it known:
  * the subject: a clock tower with a hall, a round turret and columns (boxes, cylinders,
    spheres; textured stone, a copper dome), SIZE = 1 high (the largest side of its bounding
    box x -0.4..0.4, y -0.25..0.25, z -0.5..0.5, centred at the origin), standing on
  * the square: a paved ground (top z = -0.5), façades at WALL = 24 from the centre, 6.5 high,
    and a sky above closing the room, so that every ray ends on a surface (declared unbounded);
  * the cameras: anywhere around it (azimuth uniform), 5°-30° above the horizon, 2 to 9 subject
    sizes from its centre (log-uniform), looking at it;
  * each training photo's own zoom and lens (`Effects.lens`): focal lengths spread ZOOM = 3x
    (log-uniformly, evenly spaced and shuffled, so the largest is exactly 3x the smallest) around
    the stored focal, their median, and a radial distortion k1 ~ U[-0.5, -0.2], k2 = 0.6 k1²
    (0.024-0.15: r_d(r) rises everywhere, so every pixel has one ray). The Dataset stores ONE
    pinhole camera, the median focal without distortion, as an LLFF file made from a shared
    COLMAP SIMPLE_RADIAL camera does; `lenses` gives the true ones (`true_cameras` as Cameras);
  * passers-by in 60% of the training photos (occluders.py), standing 25-60% of the way to the
    subject, drawn again while they hide more than half of it; per-photo looks (photos.py);
  * masks (`Dataset.masks`): 1 exactly where the pixel's first hit is the subject (not the
    ground, the sky or a passer-by), on every view.
The held-out views are the static scene through the stored pinhole under the neutral look, with
their masks: the exact ground truth of what a model of the stored camera should render.
Lambertian and unshadowed (the sky's slab would shadow everything, as in garden.py).
Bounds: near = 0.4, below the nearest z-depth any photo sees (the ground at a wide photo's bottom
corner, 0.59); far = 60, above the farthest (a far corner of the square, 42.5).
"""

import dataclasses

import numpy as np

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data import lens
from nerf_jax.data.dataset import Dataset
from nerf_jax.data.scenes import garden, occluders, simulator
from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from nerf_jax.data.scenes.scene import Effects, Light, Material, Object, Scene
from nerf_jax.data.scenes.textures import Texture

SIZE = 1.0  # the subject's size: the largest side of its bounding box (its height)
GROUND_Z = -0.5 * SIZE  # the square's top, the subject's foot
WALL = 24.0  # inner faces of the façades: x = +-WALL, y = +-WALL
SKY_Z = 6.0  # the sky's lower face (the highest camera is at 4.5)
DISTANCE = (2.0, 9.0)  # cameras this many subject sizes from its centre, log-uniform
ELEVATION = (5.0, 30.0)  # cameras' elevation above the horizon in degrees, uniform
ZOOM = 3.0  # the training photos' largest focal / smallest
K1 = (-0.5, -0.2)  # each training photo's k1, uniform
K2_PER_K1_SQUARED = 0.6  # k2 = 0.6 k1²: > 0.45 k1² keeps r (1 + k1 r² + k2 r⁴) increasing
PASSER_DISTANCE = (0.25, 0.6)  # passers-by stand this share of the camera's distance away
MAX_DRAWS = 50  # a photo's passers-by are drawn again while they hide over half the subject
NEAR, FAR = 0.4, 60.0
# Streams of their own (see photos.GAIN_STREAM).
CAMERA_STREAM, LENS_STREAM = 0x1A2D, 0x1E25


def _subject():
  """The monument's objects, centred at the origin, foot on z = GROUND_Z."""
  stone = Material((0.8, 0.72, 0.58), texture=Texture(
      noise=0.35, noise_scale=6.0, stripes=0.06, stripe_axis=(0.0, 0.0, 1.0), stripe_warp=0.15,
      stripe_color=(0.55, 0.48, 0.4), seed=21))
  copper = Material((0.35, 0.68, 0.58), texture=Texture(noise=0.5, noise_scale=10.0, seed=22))
  belfry = Material((0.85, 0.82, 0.7), texture=Texture(glyphs=0.04, noise=0.2, seed=23))
  brick = Material((0.7, 0.35, 0.28), texture=Texture(noise=0.4, noise_scale=12.0, seed=24))
  marble = Material((0.9, 0.9, 0.86), texture=Texture(noise=0.2, noise_scale=20.0, seed=25))
  return (
      Object(Box((0.0, 0.0, -0.47), (0.8, 0.5, 0.06)), stone),  # the plinth
      Object(Box((0.0, 0.0, -0.12), (0.3, 0.3, 0.64)), stone),  # the shaft
      Object(Box((0.0, 0.0, 0.25), (0.34, 0.34, 0.1)), belfry),  # the clock's storey
      Object(Sphere((0.0, 0.0, 0.3), 0.15), copper),  # the dome (its lower half inside)
      Object(Sphere((0.0, 0.0, 0.475), 0.025), copper),  # the finial, top at z = 0.5
      Object(Box((0.275, 0.0, -0.29), (0.25, 0.4, 0.3)), brick),  # the hall
      Object(Cylinder((-0.3, 0.0, -0.24), 0.09, 0.4), stone),  # the turret
      Object(Sphere((-0.3, 0.0, -0.04), 0.09), copper),  # its cap
      Object(Cylinder((0.22, -0.22, -0.29), 0.025, 0.3), marble),  # columns before the hall
      Object(Cylinder((0.33, -0.22, -0.29), 0.025, 0.3), marble),
  )


def _square():
  """The paved ground, four façades and the sky (garden.enclosure)."""
  paving = Material((0.62, 0.6, 0.56), texture=Texture(
      noise=0.45, noise_scale=2.0, stripes=0.7, stripe_axis=(1.0, 1.0, 0.0), stripe_warp=0.1,
      stripe_color=(0.45, 0.44, 0.42), seed=26))
  facade = Material((0.85, 0.75, 0.6), texture=Texture(
      noise=0.3, noise_scale=0.5, stripes=2.5, stripe_axis=(0.0, 0.0, 1.0), stripe_warp=0.2,
      stripe_color=(0.3, 0.32, 0.4), seed=27))
  sky = Material((0.55, 0.72, 0.95), texture=Texture(noise=0.4, noise_scale=0.1, seed=28))
  return garden.enclosure(WALL, 1.0, GROUND_Z, SKY_Z, paving, facade, sky)


SUBJECT = _subject()  # SCENE.objects[:len(SUBJECT)]
SCENE = Scene("landmark", SUBJECT + _square(),
              Effects(unbounded=True, appearance=True, transients=True, lens=True),
              light=Light(direction=(0.5, -0.3, 0.8), color=(0.65, 0.65, 0.65),
                          ambient=(0.35, 0.35, 0.35)),
              elevation=ELEVATION, near=NEAR, far=FAR)


def poses(num_views, seed=0):
  """Cameras float32 [N, 4, 4] looking at the subject's centre: azimuth ~ U[0, 360), elevation
  ~ U(ELEVATION), distance log-uniform in DISTANCE x SIZE, drawn with default_rng((seed,
  CAMERA_STREAM))."""
  rng = np.random.default_rng([seed, CAMERA_STREAM])
  thetas = rng.uniform(0.0, 360.0, num_views)
  phis = rng.uniform(*ELEVATION, num_views)
  distances = SIZE * np.exp(rng.uniform(*np.log(DISTANCE), num_views))
  return np.stack([rays_lib.pose_spherical(t, -p, d) for t, p, d in zip(thetas, phis, distances)])


def lenses(num_photos, focal, seed=0, zoom=True, distortion=True):
  """The true cameras of `num_photos` training photos whose stored pinhole has `focal` (pixels):
  (focals float64 [N], focal * ZOOM^s with s the N points evenly spaced over [-1/2, 1/2] (0 for
  one photo), shuffled: their median is `focal`; dist float64 [N, 2], each photo's (k1, k2)).
  zoom=False: every focal is `focal`; distortion=False: every (k1, k2) is 0 (a pinhole), the
  draws unchanged, so that each part can be left out alone (data.without)."""
  rng = np.random.default_rng([seed, LENS_STREAM])
  spread = np.linspace(-0.5, 0.5, num_photos) if num_photos > 1 else np.zeros(num_photos)
  focals = focal * ZOOM ** rng.permutation(spread)
  k1 = rng.uniform(*K1, num_photos)
  dist = np.stack([k1, K2_PER_K1_SQUARED * k1 * k1], -1)
  return (focals if zoom else np.full(num_photos, float(focal)),
          dist if distortion else np.zeros_like(dist))


def true_cameras(dataset, seed=0):
  """The training photos' true cameras, as a model would be handed them: (Cameras, each photo's
  size and focal (centred principal point); dist float64 [N, 4], OpenCV's (k1, k2, 0, 0)).
  dataset: the training Dataset `photographed(..., seed)` took."""
  focals, dist = lenses(len(dataset), dataset.focal, seed)
  height, width = dataset.height, dataset.width
  cameras = Cameras.stack([(height, width, (f, f, 0.5 * width, 0.5 * height)) for f in focals])
  return cameras, np.concatenate([dist, np.zeros_like(dist)], -1)


def photo_rays(pose, height, width, focal, dist=(0.0, 0.0), pixel_center=0.5):
  """Rays of every pixel of a photo taken through a radial lens: (origins, directions), float64
  [H * W, 3], row-major.

  pose: float [4, 4] camera-to-world. focal: float, pixels. dist: (k1, k2); (0, 0) = a pinhole.
  Pixel (i, j)'s distorted normalised coordinates, lens.py's (y down), are ((i + pixel_center -
  W/2) / focal, (j + pixel_center - H/2) / focal); `lens.undistort` with (k1, k2, 0, 0) gives the
  pinhole coordinates (x, y), and the ray goes through (x, -y, -1) in the camera
  (`nerf_jax.cameras.rays`: y up, looking down -z), un-normalised: its parameter is the z-depth.
  """
  u, v = np.meshgrid(np.arange(width) + pixel_center, np.arange(height) + pixel_center,
                     indexing="xy")
  xy = np.stack([u - 0.5 * width, v - 0.5 * height], -1).reshape(-1, 2) / focal
  if any(dist):
    xy = lens.undistort(xy, (float(dist[0]), float(dist[1]), 0.0, 0.0))
  cam = np.concatenate([xy[:, :1], -xy[:, 1:], -np.ones_like(xy[:, :1])], -1)
  pose = np.asarray(pose, np.float64)
  return np.broadcast_to(pose[:3, 3], cam.shape), cam @ pose[:3, :3].T


def trace(origins, directions, near=NEAR, far=FAR, chunk=1 << 16):
  """The static scene along rays float64 [R, 3] (the simulator's ground truth: every ray ends on
  a surface): (rgb float64 [R, 3], depth float64 [R], subject bool [R], first hit on SUBJECT).
  The rays are padded to whole chunks so that the textures compile for one size only (a power
  of two from 1024 for fewer rays)."""
  num = len(origins)
  chunk = min(chunk, max(1024, 1 << (num - 1).bit_length()))
  pad = lambda a: np.concatenate([a, np.broadcast_to(a[:1], (-num % chunk, 3))])
  origins, directions = pad(origins), pad(directions)
  rgb, depth, subject = [], [], []
  for i in range(0, len(origins), chunk):
    o, d = origins[i:i + chunk], directions[i:i + chunk]
    t, index, normal = simulator.first_hit(SCENE.objects, o, d, near, far)
    if not np.all(np.isfinite(t)):
      raise ValueError("landmark: a ray left the square")  # the room is closed: a bug
    unit = d / np.linalg.norm(d, axis=-1, keepdims=True)
    rgb.append(simulator.surface_rgb(SCENE, index, o + t[:, None] * d, normal, unit))
    depth.append(t)
    subject.append(index < len(SUBJECT))
  return np.concatenate(rgb)[:num], np.concatenate(depth)[:num], np.concatenate(subject)[:num]


def _views(cams, height, width, focals, dists, pixel_center, near, far):
  """Photos of the static scene taken by cams float [N, 4, 4] through focals float [N] and
  dists (k1, k2) float [N, 2]: (rgb float64 [N, H, W, 3], depth float64 [N, H, W], subject bool
  [N, H, W], origins and directions float64 [N, H * W, 3])."""
  rays = [photo_rays(p, height, width, f, k, pixel_center)
          for p, f, k in zip(cams, focals, dists)]
  origins, directions = np.stack([o for o, _ in rays]), np.stack([d for _, d in rays])
  rgb, depth, subject = trace(origins.reshape(-1, 3), directions.reshape(-1, 3), near, far)
  shape = (len(cams), height, width)
  return (rgb.reshape(*shape, 3), depth.reshape(shape), subject.reshape(shape), origins,
          directions)


def make_dataset(num_views, height, width, focal, pixel_center=0.5, near=None, far=None,
                 seed=0):
  """The static scene through the stored pinhole (`focal`, pixels) from `poses(num_views,
  seed)`: images, depths, accs (1) and the subject's masks. near, far: None = NEAR, FAR."""
  near = NEAR if near is None else near
  far = FAR if far is None else far
  cams = poses(num_views, seed)
  rgb, depth, subject, _, _ = _views(cams, height, width, np.full(num_views, focal),
                                     np.zeros((num_views, 2)), pixel_center, near, far)
  return Dataset(images=rgb.astype(np.float32), poses=cams,
                 intrinsics=(float(focal), float(focal), width * 0.5, height * 0.5),
                 near=near, far=far, depths=depth.astype(np.float32),
                 accs=np.ones(depth.shape, np.float32), name=SCENE.name,
                 pixel_center=float(pixel_center), masks=subject)


def _passers_by(pose, origins, directions, depth, subject, shape, focal, rng):
  """One crowded photo's passers-by (occluders.crowd), drawn until they leave at least half of
  the subject's pixels seen: (t float64 [H * W], inf where none; rgb float64 [H * W, 3]).
  origins, directions float64 [H * W, 3]; depth float64 [H * W]; subject bool [H * W]."""
  distance = np.linalg.norm(pose[:3, 3])
  for _ in range(MAX_DRAWS):
    objects = occluders.crowd(pose, *shape, focal, rng,
                              tuple(s * distance for s in PASSER_DISTANCE))
    t, rgb = occluders.shade(objects, origins, directions, SCENE.light)
    if np.sum(subject & (t >= depth)) >= 0.5 * np.sum(subject):
      return t, rgb
  raise ValueError(f"landmark: {MAX_DRAWS} crowds in a row hid the subject")


def photographed(dataset, transients=True, seed=0, zoom=True, distortion=True):
  """The training views `dataset` (a Dataset of `make_dataset`) as the photographers took them:
  each through its own lens (`lenses(len(dataset), dataset.focal, seed)`), passers-by in the
  photos `occluders.crowded_views(N, seed)` picks (with `transients`); the stored camera is
  unchanged. Returns (dataset, passers bool [N, H, W], True where a passer-by is seen); its
  masks keep the subject's pixels that no passer-by hides. zoom, distortion: `lenses`'."""
  num, height, width = len(dataset), dataset.height, dataset.width
  focals, dists = lenses(num, dataset.focal, seed, zoom, distortion)
  cams = np.asarray(dataset.poses, np.float64)
  rgb, depth, subject, origins, directions = _views(
      cams, height, width, focals, dists, dataset.pixel_center, dataset.near, dataset.far)
  passers = np.zeros(depth.shape, bool)
  if transients:
    rng = np.random.default_rng([seed, occluders.CROWD_STREAM, 2])
    for k in np.flatnonzero(occluders.crowded_views(num, seed)):
      t, colour = _passers_by(cams[k], origins[k], directions[k], depth[k].reshape(-1),
                              subject[k].reshape(-1), (height, width), focals[k], rng)
      t, colour = t.reshape(height, width), colour.reshape(height, width, 3)
      passers[k] = front = t < depth[k]
      rgb[k][front], depth[k][front] = colour[front], t[front]
  return dataclasses.replace(dataset, images=rgb.astype(np.float32),
                             depths=depth.astype(np.float32),
                             accs=np.ones(depth.shape, np.float32),
                             masks=subject & ~passers), passers
