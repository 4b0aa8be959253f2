"""What a crowd adds to a photo collection: passers-by between the camera and the subject.

A share of the training photos (`SHARE`) each has one to three opaque occluders of its own, a
ball, a box or a person (a cylinder with a ball for a head), of a random colour, standing 1.6 to
2.6 units in front of the camera (the subject's nearest point is ~2.8 away) on the line to a
point of the image's middle, sized so that together they cover about 5-25 % of the image
(`COVER`; from their projected sizes, so the realised share differs a little). They are lit by
the scene's light, unshadowed, and seen from distance 0 (a passer-by may stand closer than the
scene's near bound, as at a real landmark). The held-out views never have any: a test view
shows the static scene only, its exact ground truth (`Effects.transients`, photos.photographed).
"""

import dataclasses

import numpy as np

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data.scenes import simulator
from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from nerf_jax.data.scenes.scene import Light, Material, Object

# A stream of its own (see photos.GAIN_STREAM): which photos are crowded is tied to neither the
# cameras nor the gains.
CROWD_STREAM = 0xC40D
SHARE = 0.6  # share of the training photos with occluders
COVER = (0.05, 0.25)  # each crowded photo: the occluders' target share of the image, uniform
DISTANCE = (1.6, 2.6)  # occluders stand this far from the camera, uniform
MAX_OCCLUDERS = 3  # one to this many per crowded photo


def _occluder(center, radius, kind, colour):
  """Objects of one occluder of `kind` 0 (ball), 1 (box) or 2 (person) centred at `center`
  (float [3]) whose silhouette has about the area of a disc of `radius` (world units)."""
  material = Material(tuple(float(c) for c in colour))
  x, y, z = (float(c) for c in center)
  if kind == 0:
    return (Object(Sphere((x, y, z), radius), material),)
  if kind == 1:  # a cube of the disc's area, seen face on
    side = radius * np.sqrt(np.pi)
    return (Object(Box((x, y, z), (side, side, side)), material),)
  # A person: a body 2r wide and ~2.8r tall (area ~5.6r² + the head's ~1.1r² ≈ 2.1 discs of
  # radius r, so r is scaled by 1/sqrt(2.1)).
  r = radius / np.sqrt(2.1)
  body = Object(Cylinder((x, y, z - 0.4 * r), r, 2.8 * r), material)
  head = Object(Sphere((x, y, z + 1.6 * r), 0.6 * r), material)
  return body, head


def crowd(pose, height, width, focal, rng, distance=DISTANCE):
  """The occluders of one crowded photo taken by `pose` (float32 [4, 4]) at height x width
  pixels with `focal` (pixels), drawn from `rng` (np.random.Generator), standing `distance`
  (min, max) from the camera: a tuple of `Object`s."""
  count = int(rng.integers(1, MAX_OCCLUDERS + 1))
  target = rng.uniform(*COVER) / count  # each occluder's share of the image
  objects = []
  for _ in range(count):
    u, v = rng.uniform(0.2, 0.8, 2) * (width, height)  # a point of the image's middle
    ray = np.array([(u - 0.5 * width) / focal, -(v - 0.5 * height) / focal, -1.0])
    direction = pose[:3, :3] @ (ray / np.linalg.norm(ray))
    away = rng.uniform(*distance)
    center = pose[:3, 3] + away * direction
    # A disc of radius R pixels covers π R² of the image's H·W; R = focal · radius / distance.
    radius = away * np.sqrt(target * height * width / np.pi) / focal
    objects += _occluder(center, radius, int(rng.integers(0, 3)), rng.uniform(0.05, 0.95, 3))
  return tuple(objects)


def shade(objects, origins, directions, light):
  """`objects` seen from distance 0 along rays origins, directions float64 [R, 3], lit by
  `light`, unshadowed: (t float64 [R], inf where none is hit; rgb float64 [R, 3], 0 there)."""
  t, which, normal = simulator.first_hit(objects, origins, directions, 0.0, np.inf)
  hit = np.isfinite(t)
  rgb = np.zeros_like(origins)
  albedo = np.array([o.material.albedo for o in objects])[which[hit]]
  rgb[hit] = simulator.diffuse(albedo, normal[hit], light, np.ones(hit.sum()))
  return t, rgb


def paint(dataset, index, objects, light):
  """Image `index` of `dataset` (a Dataset, one pinhole camera) with `objects` in front of its
  scene, lit by `light`: (rgb float32 [H, W, 3], depth float32 [H, W] or None, hit bool
  [H, W], where an occluder is seen)."""
  height, width = dataset.height, dataset.width
  origins, directions = rays_lib.get_rays(height, width, dataset.intrinsics[0],
                                          dataset.poses[index], dataset.pixel_center)
  origins = np.asarray(origins, np.float64).reshape(-1, 3)
  directions = np.asarray(directions, np.float64).reshape(-1, 3)
  t, colour = shade(objects, origins, directions, light)
  hit = np.isfinite(t)
  rgb = np.array(dataset.images[index], np.float64).reshape(-1, 3)
  rgb[hit] = colour[hit]
  depth = None
  if dataset.depths is not None:  # depths are distances along the un-normalised directions
    depth = np.array(dataset.depths[index], np.float64).reshape(-1)
    depth[hit] = t[hit]
  shape = (height, width)
  return (np.clip(rgb, 0, 1).reshape(*shape, 3).astype(np.float32),
          None if depth is None else depth.reshape(shape).astype(np.float32), hit.reshape(shape))


def crowded_views(num_views, seed=0):
  """bool [num_views]: the photos that have occluders (a SHARE of them, rounded, at random)."""
  rng = np.random.default_rng([seed, CROWD_STREAM])
  chosen = np.zeros(num_views, bool)
  chosen[rng.permutation(num_views)[:int(round(SHARE * num_views))]] = True
  return chosen


def with_crowd(dataset, light=Light(), seed=0):
  """(dataset, masks): `dataset` (a Dataset of one pinhole camera) with occluders in a SHARE of
  its photos (`crowd`, lit by `light`; their accs 1 and depths theirs where seen), and bool
  [N, H, W], True where an occluder hides the scene (the exact transient masks)."""
  rng = np.random.default_rng([seed, CROWD_STREAM, 1])
  images = np.array(dataset.images, np.float32)
  depths = None if dataset.depths is None else np.array(dataset.depths, np.float32)
  accs = None if dataset.accs is None else np.array(dataset.accs, np.float32)
  masks = np.zeros(images.shape[:3], bool)
  for k in np.flatnonzero(crowded_views(len(dataset), seed)):
    objects = crowd(np.asarray(dataset.poses[k], np.float64), dataset.height, dataset.width,
                    dataset.intrinsics[0], rng)
    images[k], depth, masks[k] = paint(dataset, k, objects, light)
    if depths is not None:
      depths[k] = depth
    if accs is not None:
      accs[k][masks[k]] = 1.0
  return dataclasses.replace(dataset, images=images, depths=depths, accs=accs), masks
