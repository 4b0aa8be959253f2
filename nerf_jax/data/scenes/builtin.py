"""The built-in scenes and their posed ground-truth datasets.

Two camera rigs (`Scene.camera_rig`):
  'hemisphere' — the 360° scenes fit in a ball of radius ~1.2 around the origin (z up), so that
    cameras at radius 4 with near = 2, far = 6 and tiny_nerf's 40° field of view see them whole;
    the elevations are the scene's (`Scene.elevation`: 10°-80°, the unbounded `garden` 2°-20°);
  'forward' — an LLFF-like capture: cameras on the plane z = 0 within +-0.3 in x and y, all with
    the identity rotation (looking down -z, y up), in front of objects and a back wall that fills
    every view, so that world coordinates are already those NDC (`nerf_jax.cameras.ndc`) expects.
"""

import dataclasses

import jax
import numpy as np

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data.dataset import Dataset
from nerf_jax.data.scenes import (cache, detail, garden, landmark, landmark_sfm, multiscale,
                                  simulator)
from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from nerf_jax.data.scenes.scene import Effects, Light, Material, Medium, Object, Scene

TINY_NERF_FOCAL = 138.88887889922103  # focal of tiny_nerf's 100 x 100 images, in pixels

# `get_rays` of every pose [N, 4, 4] at once (jit compiles in half the time of eager vmap).
_batched_rays = jax.jit(jax.vmap(rays_lib.get_rays, in_axes=(None, None, None, 0, None)),
                        static_argnums=(0, 1))

RED, GREEN, BLUE = (0.9, 0.2, 0.15), (0.2, 0.75, 0.3), (0.2, 0.35, 0.9)
YELLOW, PURPLE, GREY = (0.9, 0.75, 0.2), (0.65, 0.3, 0.8), (0.65, 0.65, 0.6)


def _objects(specular=0.0, pedestal=True):
  """Spheres and boxes of several colours, optionally standing on a grey disc (top at z = -0.5).

  specular: float, Blinn-Phong strength of the spheres (half of it on the boxes and the disc).
  """
  gloss = lambda albedo, s, n: Material(albedo, specular * s, n)
  objects = [
      Object(Sphere((0.0, 0.0, 0.0), 0.5), gloss(RED, 1.0, 40.0)),
      Object(Sphere((0.62, -0.45, -0.22), 0.28), gloss(GREEN, 1.0, 20.0)),
      Object(Sphere((-0.5, 0.55, -0.3), 0.2), gloss(BLUE, 1.0, 60.0)),
      Object(Box((-0.5, -0.45, -0.25), (0.4, 0.4, 0.5)), gloss(YELLOW, 0.5, 20.0)),
      Object(Box((0.45, 0.5, -0.1), (0.25, 0.25, 0.8)), gloss(PURPLE, 0.5, 20.0)),
  ]
  if pedestal:
    objects.append(Object(Cylinder((0.0, 0.0, -0.55), 1.0, 0.1), gloss(GREY, 0.5, 10.0)))
  return tuple(objects)


def _fog_scene():
  objects = (
      Object(Sphere((0.5, 0.3, -0.1), 0.35), Material(YELLOW)),  # straddles the fog's edge
      Object(Box((0.0, 0.0, -0.2), (0.3, 0.3, 0.6)), Material(RED)),  # inside the fog
      Object(Box((-0.65, -0.55, -0.3), (0.35, 0.35, 0.4)), Material(GREEN)),  # outside
      Object(Cylinder((0.0, 0.0, -0.55), 1.0, 0.1), Material(GREY)),
  )
  fog = Medium(Sphere((0.0, 0.0, 0.0), 0.75), density=1.2, color=(0.35, 0.6, 1.0))
  return Scene("fog", objects, Effects(participating_medium=True, shadows=True), medium=fog)


def _forward_scene():
  """Lambertian objects 1.85 to 4.6 in front of the cameras and a checkered wall at depth 5.

  The wall (16 x 16) fills the view of every camera up to a ~110° field of view, so every ray
  hits something, as in a real capture. Bounds: 0.9x the nearest depth (the yellow disc's face
  at 1.85) and 1.1x the farthest (the wall at 5).
  """
  wall = Material((0.85, 0.8, 0.7), checker=0.5, albedo2=(0.35, 0.5, 0.6))
  objects = (
      Object(Box((0.0, 0.0, -5.1), (16.0, 16.0, 0.2)), wall),
      Object(Cylinder((-0.35, -0.4, -1.95), 0.22, 0.2), Material(YELLOW)),  # a disc facing us
      Object(Box((0.5, -0.35, -2.4), (0.45, 0.45, 0.45)), Material(GREEN)),
      Object(Sphere((-0.7, 0.35, -3.2), 0.45), Material(RED)),
      Object(Sphere((0.75, 0.6, -4.0), 0.35), Material(BLUE)),
      Object(Box((-1.2, -0.4, -4.4), (0.35, 1.2, 0.35)), Material(PURPLE)),
  )
  light = Light(direction=(0.35, 0.6, 0.7))  # from the upper right, behind the cameras
  return Scene("forward", objects, Effects(shadows=True, unbounded=True), light=light,
               camera_rig="forward", near=0.9 * 1.85, far=1.1 * 5.0)


SCENES = {
    "diffuse": Scene("diffuse", _objects(pedestal=False), Effects()),
    "glossy": Scene("glossy", _objects(specular=0.6), Effects(view_dependent=True, shadows=True)),
    "fog": _fog_scene(),
    "white": Scene("white", _objects(), Effects(background=True, shadows=True),
                   background=(1.0, 1.0, 1.0)),
    "forward": _forward_scene(),
    "detail": detail.SCENE,
    # `detail` at several camera distances and resolutions (scenes/multiscale.py).
    "multiscale": multiscale.SCENE,
    "garden": garden.scene(_objects()),
    # `diffuse` as a photographer captures it (scenes/photos.py): per-photo exposure and white
    # balance, and training poses off by 1° and 2% of the scene's size.
    "exposure": Scene("exposure", _objects(pedestal=False), Effects(appearance=True)),
    "perturbed": Scene("perturbed", _objects(pedestal=False), Effects(pose_error=True)),
    # `exposure` with passers-by (scenes/occluders.py): in 60% of the training photos one to
    # three opaque balls, boxes or people stand between the camera and the subject.
    "crowd": Scene("crowd", _objects(pedestal=False), Effects(appearance=True, transients=True)),
    # A tourist photo collection (scenes/landmark.py): a monument on a square seen from 2 to 9
    # times its size, each training photo with its own zoom and lens, one pinhole stored.
    "landmark": landmark.SCENE,
    # `landmark` posed as a structure from motion forced to one shared focal poses it
    # (scenes/landmark_sfm.py): the training poses absorb each photo's zoom and lens.
    "landmark_sfm": landmark_sfm.SCENE,
}


def get_scene(name):
  """The built-in `Scene` called `name`; ValueError listing the valid names otherwise."""
  if name not in SCENES:
    raise ValueError(f"unknown scene {name!r} (valid: {', '.join(sorted(SCENES))})")
  return SCENES[name]


def random_poses(num_views, radius=4.0, seed=0, elevation=(10.0, 80.0)):
  """tiny_nerf-like cameras: float32 [num_views, 4, 4] from `pose_spherical(theta, phi, radius)`,
  theta ~ U[0, 360) then phi ~ U[-elevation[1], -elevation[0]] (degrees above the horizon; the
  default is tiny_nerf's upper hemisphere), drawn with default_rng(seed)."""
  rng = np.random.default_rng(seed)
  thetas = rng.uniform(0.0, 360.0, num_views)
  phis = rng.uniform(-elevation[1], -elevation[0], num_views)
  return np.stack([rays_lib.pose_spherical(t, p, radius) for t, p in zip(thetas, phis)])


def forward_poses(num_views, extent=0.3, seed=0):
  """LLFF-like cameras: float32 [num_views, 4, 4], identity rotations (looking down -z) at
  (x, y, 0) with x, y ~ U[-extent, extent], drawn with default_rng(seed)."""
  rng = np.random.default_rng(seed)
  poses = np.tile(np.eye(4, dtype=np.float32), (num_views, 1, 1))
  poses[:, :2, 3] = rng.uniform(-extent, extent, (num_views, 2))
  return poses


def make_dataset(name, num_views=100, height=None, width=None, focal=None, radius=4.0,
                 pixel_center=0.5, seed=0, near=None, far=None):
  """Ground-truth `Dataset` of a built-in scene (with `depths` and `accs`).

  The cameras follow the scene's rig: `random_poses(num_views, radius, seed, scene.elevation)` or
  `forward_poses(num_views, seed=seed)` (radius is ignored). height, width: int or None (= the
  scene's `image_size`). focal: float or None (= tiny_nerf's field of view at this width).
  near, far: float or None (= the scene's bounds). pixel_center: where in each pixel its ray
  passes (0.5 centres, as a renderer samples; 0 corners), recorded in the Dataset. A scene with
  `supersample > 1` is rendered by `tracer` (s x s rays per pixel), through the disk `cache`
  when large. 'multiscale' (scenes/multiscale.py): views at several distances and sizes
  (height = level 0's side, width ignored; near, far None = its own). 'landmark'
  (scenes/landmark.py) and 'landmark_sfm' (its twin, the same views): its own cameras (radius
  ignored), `focal` the stored pinhole's.
  """
  scene = get_scene(name)
  bounds = (near, far)  # as asked: the multiscale scene has its own defaults
  near = scene.near if near is None else near
  far = scene.far if far is None else far
  height = scene.image_size if height is None else height
  width = scene.image_size if width is None else width
  focal = TINY_NERF_FOCAL * width / 100 if focal is None else focal
  if name in (landmark.SCENE.name, landmark_sfm.SCENE.name):
    return dataclasses.replace(landmark.make_dataset(num_views, height, width, focal,
                                                     pixel_center, near, far, seed), name=name)
  if scene.camera_rig == "forward":
    poses = forward_poses(num_views, seed=seed)
  else:
    poses = random_poses(num_views, radius, seed, scene.elevation)
  if name == multiscale.SCENE.name:  # per-image cameras: its own module
    return multiscale.make_dataset(poses, height, focal, pixel_center, *bounds, seed)
  shape = (num_views, height, width)
  if scene.supersample > 1:
    out = cache.render_images(scene, poses, height, width, focal, pixel_center, near, far)
  else:
    origins, directions = _batched_rays(height, width, focal, poses, pixel_center)
    out = simulator.trace_rays(scene, np.reshape(origins, (-1, 3)),
                                np.reshape(directions, (-1, 3)), near, far)
  return Dataset(
      images=out["rgb"].reshape(*shape, 3).astype(np.float32), poses=poses,
      intrinsics=(float(focal), float(focal), width * 0.5, height * 0.5), near=near, far=far,
      depths=out["depth"].reshape(shape).astype(np.float32),
      accs=out["acc"].reshape(shape).astype(np.float32), name=name,
      background=tuple(float(c) for c in scene.background),
      forward_facing=scene.camera_rig == "forward", pixel_center=float(pixel_center))
