"""Scene descriptions: opaque objects, lighting, an optional fog, and the declared effects.

A scene is plain, frozen data; `scenes.simulator` renders it. The `effects` declaration
is checked against the content (`Scene.__post_init__`) and decides what the simulator computes:
an effect that is not declared is never evaluated. (`unbounded` asks nothing more of the
simulator; it tells a renderer that the content reaches beyond a bounded box. `appearance`,
`pose_error`, `transients`, `lens` and `sfm_poses` (`CAPTURE`) are the capture's, not the
content's: scenes/photos.py applies them to the training views.)
"""

import dataclasses
from typing import Optional, Union

from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from nerf_jax.data.scenes.raycast import Rod

Shape = Union[Sphere, Box, Cylinder, Rod]

# A bounded scene's content lies inside the cube [-INNER_EXTENT, INNER_EXTENT]^3 (the 360° scenes
# fit in a ball of radius ~1.2; cameras at radius 4 with near = 2 see the cube's content whole).
# Content outside it is the `unbounded` effect.
INNER_EXTENT = 2.0


@dataclasses.dataclass(frozen=True)
class Material:
  albedo: tuple  # diffuse RGB reflectance in [0, 1]
  specular: float = 0.0  # Blinn-Phong strength; > 0 makes the object view dependent
  shininess: float = 32.0  # Blinn-Phong exponent
  checker: float = 0.0  # > 0: squares of this side in world x-y alternate albedo and albedo2
  albedo2: tuple = (0.0, 0.0, 0.0)  # the second checker colour
  texture: object = None  # a `nerf_jax.data.scenes.textures.Texture` modulating albedo, or None


@dataclasses.dataclass(frozen=True)
class Object:
  """An opaque solid."""
  shape: Shape
  material: Material


@dataclasses.dataclass(frozen=True)
class Light:
  direction: tuple = (0.4, -0.3, 0.85)  # towards the light (normalised by the simulator)
  color: tuple = (0.8, 0.8, 0.8)  # RGB radiance of the directional light
  ambient: tuple = (0.2, 0.2, 0.2)  # RGB ambient term, added to every lit or shadowed point


@dataclasses.dataclass(frozen=True)
class Medium:
  """A homogeneous emission-absorption fog filling `shape` (behind opaque objects it is hidden).

  It does not scatter light, receive shadows or cast them.
  """
  shape: Shape
  density: float  # extinction coefficient sigma > 0, per world unit of length
  color: tuple  # emitted RGB in [0, 1]: an infinitely thick fog looks this colour


@dataclasses.dataclass(frozen=True)
class Effects:
  """Which phenomena a scene contains (and the simulator computes)."""
  view_dependent: bool = False  # Blinn-Phong highlights
  participating_medium: bool = False  # a fog with 0 < opacity < 1
  background: bool = False  # a non-black background
  shadows: bool = False  # opaque objects shadow the directional light
  unbounded: bool = False  # content beyond the cube [-INNER_EXTENT, INNER_EXTENT]^3
  appearance: bool = False  # training photos differ in exposure and white balance (photos.py)
  pose_error: bool = False  # the training cameras' poses are off by a known amount (photos.py)
  transients: bool = False  # some training photos have passers-by in front (occluders.py)
  lens: bool = False  # each training photo its own zoom and radial lens; one pinhole stored
  sfm_poses: bool = False  # training poses a one-focal SfM solves (scenes/landmark_sfm.py)

  def names(self):
    """The declared effects: frozenset of field names."""
    return frozenset(f.name for f in dataclasses.fields(self) if getattr(self, f.name))


# The effects of the capture (scenes/photos.py), not of the content.
CAPTURE = frozenset({"appearance", "pose_error", "transients", "lens", "sfm_poses"})


@dataclasses.dataclass(frozen=True)
class Scene:
  name: str
  objects: tuple  # of Object
  effects: Effects
  light: Light = Light()
  background: tuple = (0.0, 0.0, 0.0)  # RGB seen by rays that hit nothing
  medium: Optional[Medium] = None
  camera_rig: str = "hemisphere"  # 'hemisphere' (orbit the origin) or 'forward' (LLFF-like)
  elevation: tuple = (10.0, 80.0)  # 'hemisphere': camera elevations in degrees above the horizon
  near: float = 2.0  # z-depth bounds of everything the rig's cameras see
  far: float = 6.0
  image_size: int = 100  # default height = width of its datasets, in pixels
  supersample: int = 1  # s > 1: s x s rays per pixel, traced by `nerf_jax.data.scenes.tracer`

  def __post_init__(self):
    if self.camera_rig not in ("hemisphere", "forward"):
      raise ValueError(f"scene {self.name!r}: camera_rig {self.camera_rig!r} is not "
                       "'hemisphere' or 'forward'")
    content = {
        "view_dependent": any(o.material.specular > 0 for o in self.objects),
        "participating_medium": self.medium is not None,
        "background": any(c != 0 for c in self.background),
        "unbounded": any(extent(o.shape) > INNER_EXTENT for o in self.objects)
                     or (self.medium is not None and extent(self.medium.shape) > INNER_EXTENT),
    }
    for effect, present in content.items():
      if present != getattr(self.effects, effect):
        raise ValueError(f"scene {self.name!r}: effect {effect!r} is "
                         f"{'declared' if not present else 'not declared'} but the content "
                         f"{'lacks' if not present else 'has'} it")


def extent(shape):
  """The largest |coordinate| of any point of `shape` (a `Shape`): float, the half-size of the
  smallest origin-centred cube [-e, e]^3 that holds it (from its axis-aligned bounding box)."""
  if isinstance(shape, Sphere):
    return max(abs(c) + shape.radius for c in shape.center)
  if isinstance(shape, Box):
    return max(abs(c) + 0.5 * s for c, s in zip(shape.center, shape.size))
  if isinstance(shape, Cylinder):  # vertical axis
    half = (shape.radius, shape.radius, 0.5 * shape.height)
    return max(abs(c) + h for c, h in zip(shape.center, half))
  if isinstance(shape, Rod):  # the caps' centres, padded by the radius in every direction
    return max(abs(c) + shape.radius for c in shape.start + shape.end)
  raise ValueError(f"extent: unknown shape {type(shape).__name__}")
