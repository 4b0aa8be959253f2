"""`detail`: a NeRF-synthetic-like scene — fine texture, thin parts, gloss, transparent background.

What the other built-in scenes lack, in one object group on a plinth (z up, inside a ball of
radius ~1.1, so the hemisphere rig at radius 4 sees it whole):
  * fine procedural texture (`textures`): value-noise fBm on everything, lines of glyphs on the
    plinth and the crate, noise-warped stripes on the tower and the can; non-repeating, so SIFT
    finds and matches features across views;
  * thin rods of radius 0.005-0.008 (a 128^3 grid over [-1.5, 1.5]^3 has 0.023-wide cells; at
    400 px a rod is ~1-2 px wide): an antenna, a fence with a rail, and a ring of 16 rods;
  * two glossy spheres (Blinn-Phong: declared `view_dependent`);
  * black, empty background: acc is the alpha of an RGBA image.
It is rendered by `tracer` with 3 x 3 rays per pixel (anti-aliased colour, coverage alpha, the
centre ray's exact depth), at 400 x 400 by default (`Scene.image_size`).
"""

import math

from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from nerf_jax.data.scenes.raycast import Rod
from nerf_jax.data.scenes.scene import Effects, Material, Object, Scene
from nerf_jax.data.scenes.textures import Texture

ROD_RADIUS = 0.006  # the antenna's and the ring's rods
FENCE_RADIUS = 0.008  # the fence posts
RAIL_RADIUS = 0.005  # the fence's rail

PLINTH = Box((0.0, 0.0, -0.6), (1.5, 1.5, 0.12))  # top face at z = -0.54
CRATE = Box((-0.35, -0.3, -0.29), (0.5, 0.5, 0.5))  # on the plinth, top at z = -0.04
TOWER = Box((0.4, 0.3, -0.1), (0.22, 0.22, 0.88))  # top at z = 0.34
CAN = Cylinder((-0.4, 0.4, -0.3), 0.16, 0.48)
GLOSSY = Sphere((0.32, -0.33, -0.32), 0.22)  # resting on the plinth
GOLD = Sphere((-0.35, -0.3, 0.11), 0.15)  # resting on the crate
ANTENNA = Rod((0.4, 0.3, 0.34), (0.4, 0.3, 0.95), ROD_RADIUS)


def _ring(center, radius, segments=16, tilt_deg=25.0):
  """Rods joining `segments` points of a circle of `radius` around `center` in a vertical plane
  (spanned by z and the x axis turned `tilt_deg` about z)."""
  tilt = math.radians(tilt_deg)
  across = (math.cos(tilt), math.sin(tilt), 0.0)
  corners = [tuple(c + radius * (math.cos(a) * u + math.sin(a) * z) for c, u, z in
                   zip(center, across, (0.0, 0.0, 1.0)))
             for a in (2.0 * math.pi * k / segments for k in range(segments + 1))]
  return [Rod(p, q, ROD_RADIUS) for p, q in zip(corners[:-1], corners[1:])]


def _fence(y=-0.66, xs=(-0.6, -0.45, -0.3, -0.15, 0.0, 0.15, 0.3, 0.45, 0.6), top=-0.2):
  """Vertical posts standing on the plinth at (x, y) and a rail through their tops."""
  posts = [Rod((x, y, -0.54), (x, y, top), FENCE_RADIUS) for x in xs]
  return posts + [Rod((xs[0], y, top - 0.03), (xs[-1], y, top - 0.03), RAIL_RADIUS)]


def _objects():
  paper = Material((0.85, 0.8, 0.68), texture=Texture(noise=0.35, glyphs=0.07, seed=1))
  cardboard = Material((0.7, 0.5, 0.3), texture=Texture(
      noise=0.45, noise_scale=10.0, glyphs=0.1, glyph_color=(0.1, 0.05, 0.3), seed=2))
  tower = Material((0.85, 0.85, 0.9), texture=Texture(
      noise=0.3, stripes=0.05, stripe_axis=(0.3, 0.2, 1.0), stripe_color=(0.1, 0.25, 0.7),
      seed=3))
  can = Material((0.9, 0.75, 0.2), texture=Texture(
      noise=0.4, stripes=0.035, stripe_axis=(0.0, 0.0, 1.0), stripe_warp=1.5,
      stripe_color=(0.55, 0.1, 0.1), seed=4))
  glossy = Material((0.75, 0.12, 0.1), specular=0.8, shininess=60.0,
                    texture=Texture(noise=0.5, noise_scale=6.0, seed=5))
  gold = Material((0.85, 0.65, 0.2), specular=0.9, shininess=120.0,
                  texture=Texture(noise=0.3, noise_scale=12.0, seed=6))
  metal = Material((0.6, 0.62, 0.65), texture=Texture(noise=0.6, noise_scale=20.0, seed=7))
  solids = [Object(PLINTH, paper), Object(CRATE, cardboard), Object(TOWER, tower),
            Object(CAN, can), Object(GLOSSY, glossy), Object(GOLD, gold)]
  ring = _ring((0.0, 0.25, 0.2), 0.32)
  stand = Rod((0.0, 0.25, -0.54), (0.0, 0.25, 0.2 - 0.32), ROD_RADIUS)  # holds the ring up
  rods = [ANTENNA, stand] + ring + _fence()
  return tuple(solids + [Object(r, metal) for r in rods])


SCENE = Scene("detail", _objects(), Effects(view_dependent=True), image_size=400, supersample=3)
