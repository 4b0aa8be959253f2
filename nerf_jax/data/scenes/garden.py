"""`garden`: an unbounded scene — objects in the middle, more around them, walls and a sky.

What a real 360° capture sees and the other hemisphere scenes lack: content at every distance,
so that no box around the middle holds the scene (declared `unbounded`; see
`fields.contraction`). World z is up; the cameras orbit at radius 4, low (2°-20° above the
horizon, looking at the origin), so that every view shows the ground, the middle and the walls:
  * the middle (within radius ~1.2, as the other 360° scenes): the spheres and boxes of
    `builtin._objects` on their grey disc;
  * the ground: a textured slab whose top (z = -0.6) carries the disc, out to the walls;
  * at 5.5-7.5 from the centre: three trees (a trunk and a round crown), a shed and a boulder;
  * the walls: four textured walls at 16 (inner faces) from the centre, 10.6 high, and a ceiling
    (the sky) on top, closing the room, so that every ray ends on a surface: opacity 1 and an
    exact z-depth in every pixel.
Lambertian, unshadowed (a directional light from above lights the walls' inner faces as sky
light would; shadows from the ceiling would darken everything), textured with value noise so
the distant surfaces are learnable and matchable, not flat.
Bounds: near = 1.7, ~0.9x the nearest depth the rig sees (the ground in the bottom corners of a
2° camera's view, 1.88); far = 40, 1.5x the farthest (a far wall, 26.5).
"""

from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from nerf_jax.data.scenes.scene import Effects, Light, Material, Object, Scene
from nerf_jax.data.scenes.textures import Texture

GROUND_Z = -0.6  # top of the ground slab (the bottom of the disc in the middle)
WALL = 16.0  # inner faces of the walls: x = +-WALL, y = +-WALL
SKY_Z = 10.0  # the ceiling's lower face
THICK = 1.0  # walls, ground and ceiling are slabs of this thickness (solid, no gaps at corners)


def enclosure(wall, thick, ground_z, sky_z, ground, walls, sky):
  """Ground, four walls and a ceiling closing a square world: boxes of thickness `thick`
  overlapping at the edges (solid, no gaps at corners), the walls' inner faces at x, y = +-wall,
  the ground's top at ground_z, the ceiling's lower face at sky_z; their Materials `ground`,
  `walls`, `sky`."""
  span = 2.0 * (wall + thick)  # outer size, corners included
  height = sky_z - ground_z
  mid_z = 0.5 * (sky_z + ground_z)
  wall_x = lambda x: Box((x, 0.0, mid_z), (thick, span, height))
  wall_y = lambda y: Box((0.0, y, mid_z), (span, thick, height))
  offset = wall + 0.5 * thick
  return (
      Object(Box((0.0, 0.0, ground_z - 0.5 * thick), (span, span, thick)), ground),
      Object(wall_x(offset), walls), Object(wall_x(-offset), walls),
      Object(wall_y(offset), walls), Object(wall_y(-offset), walls),
      Object(Box((0.0, 0.0, sky_z + 0.5 * thick), (span, span, thick)), sky),
  )


def _room():
  """Grass, brick walls and a sky closing the garden (`enclosure`)."""
  grass = Material((0.45, 0.6, 0.3), texture=Texture(noise=0.55, noise_scale=1.5, seed=11))
  brick = Material((0.75, 0.5, 0.4), texture=Texture(
      noise=0.35, noise_scale=0.4, stripes=1.2, stripe_axis=(0.0, 0.0, 1.0), stripe_warp=0.3,
      stripe_color=(0.55, 0.5, 0.45), seed=12))
  sky = Material((0.55, 0.7, 0.95), texture=Texture(noise=0.5, noise_scale=0.15, seed=13))
  return enclosure(WALL, THICK, GROUND_Z, SKY_Z, grass, brick, sky)


def _surroundings():
  """Trees, a shed and a boulder standing on the ground 5.5-7.5 from the centre."""
  bark = Material((0.45, 0.32, 0.2), texture=Texture(noise=0.4, noise_scale=4.0, seed=14))
  leaves = Material((0.25, 0.55, 0.2), texture=Texture(noise=0.6, noise_scale=3.0, seed=15))
  shed = Material((0.7, 0.7, 0.75), texture=Texture(
      noise=0.3, stripes=0.3, stripe_axis=(1.0, 1.0, 0.0), stripe_color=(0.3, 0.35, 0.6),
      seed=16))
  stone = Material((0.6, 0.58, 0.55), texture=Texture(noise=0.5, noise_scale=2.0, seed=17))
  objects = []
  for x, y, crown in ((6.0, 3.0, 1.0), (-4.5, 5.0, 0.9), (-3.0, -6.5, 1.1)):
    objects.append(Object(Cylinder((x, y, GROUND_Z + 1.0), 0.25, 2.0), bark))  # trunk 2 high
    objects.append(Object(Sphere((x, y, GROUND_Z + 2.0 + 0.7 * crown), crown), leaves))
  objects.append(Object(Box((-6.5, -1.5, GROUND_Z + 0.9), (1.6, 2.4, 1.8)), shed))
  objects.append(Object(Sphere((4.5, -4.5, GROUND_Z + 0.4), 0.8), stone))  # half sunk
  return tuple(objects)


def scene(middle):
  """The garden around `middle`: a tuple of `Object`s inside radius ~1.2 standing on z = -0.6."""
  light = Light(direction=(0.3, -0.2, 0.9), color=(0.65, 0.65, 0.65), ambient=(0.35, 0.35, 0.35))
  return Scene("garden", tuple(middle) + _surroundings() + _room(), Effects(unbounded=True),
               light=light, elevation=(2.0, 20.0), near=1.7, far=40.0)
