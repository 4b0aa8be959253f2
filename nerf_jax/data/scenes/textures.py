"""Procedural surface textures: value noise, warped stripes and glyphs (pure jax.numpy).

A texture is a function of the surface point and its normal only, so a point has the same
diffuse colour from every camera (what structure-from-motion needs to match it across views):
  points: float32 [..., 3], world positions on a surface;
  normals: float32 [..., 3], unit outward normals there (they choose the face's 2D chart);
  albedo: float32 [..., 3] in [0, 1].
Noise and stripes are 3D fields; glyphs are drawn in a per-face 2D chart (u, v): the two world
coordinates across the normal's dominant axis, so each box face carries its own lines of marks.
Hashes are integer (uint32) so that the patterns do not repeat over the scene's extent.
"""

import dataclasses

import jax.numpy as jnp
import numpy as np

# 3 x 5 bitmaps of digits and letters, rows top to bottom, 3 bits per row (MSB = left column).
_FONT = (
    "111101101101111", "010110010010111", "111001111100111", "111001111001111",
    "101101111001001", "111100111001111", "111100111101111", "111001010010010",
    "111101111101111", "111101111001111", "010101111101101", "111100100100111",
    "111100111100111", "111100111100100", "101101111101101", "101101110101101",
    "100100100100111", "111101111100100", "110101110101101", "111010010010010",
    "101101101101111", "101101010101101", "101101010010010", "111001010100111",
    "001001001101111", "110101101101110")
# numpy: a jnp array made at import would start the XLA backend before jax.distributed joins.
GLYPHS = np.array([[int(b) for b in g] for g in _FONT], np.float32).reshape(-1, 5, 3)


@dataclasses.dataclass(frozen=True)
class Texture:
  """Modulations of a material's albedo (each is off at 0); see `albedo`."""
  noise: float = 0.0  # amplitude of value-noise fBm: albedo * (1 - noise * fbm), fbm in [0, 1)
  noise_scale: float = 8.0  # lattice cells per world unit of the coarsest noise octave
  stripes: float = 0.0  # period of the stripes (world units) along `stripe_axis`
  stripe_axis: tuple = (0.0, 0.0, 1.0)  # the stripes vary along this direction (normalised)
  stripe_warp: float = 0.6  # how many periods the noise bends the stripes by
  stripe_color: tuple = (0.1, 0.1, 0.1)  # albedo of the stripes
  glyphs: float = 0.0  # height of a line of glyphs (world units); a glyph is 3 x 5 of 7 x 7
  glyph_color: tuple = (0.05, 0.05, 0.08)  # albedo of the glyphs' ink
  seed: int = 0  # decorrelates textures of different objects


def hash01(*ints):
  """Uniform [0, 1) hash of integer lattice coordinates. ints: int32 arrays (broadcast).
  Returns float32 of the broadcast shape."""
  h = jnp.uint32(0x9E3779B9)
  for k, v in enumerate(ints):
    h = (h ^ (v.astype(jnp.uint32) * jnp.uint32((0x85EBCA6B, 0xC2B2AE35, 0x27D4EB2F,
                                                  0x165667B1, 0xD3A2646C)[k % 5])))
    h = (h ^ (h >> 15)) * jnp.uint32(0x2C1B3C6D)  # murmur-style mixing of every input bit
  h = (h ^ (h >> 12)) * jnp.uint32(0x297A2D39)
  h = h ^ (h >> 15)
  return (h >> 8).astype(jnp.float32) * (1.0 / (1 << 24))


def value_noise(points, seed=0):
  """Trilinear value noise with a smoothstep fade. points: float32 [..., 3] in lattice units;
  seed: int or int32 [...]. Returns float32 [...] in [0, 1)."""
  cell = jnp.floor(points)
  f = points - cell
  f = f * f * (3.0 - 2.0 * f)  # smoothstep: C1 across cell faces
  ijk = cell.astype(jnp.int32)
  out = 0.0
  for corner in range(8):
    c = [(corner >> a) & 1 for a in range(3)]
    w = 1.0
    for a in range(3):
      w = w * (f[..., a] if c[a] else 1.0 - f[..., a])
    out = out + w * hash01(ijk[..., 0] + c[0], ijk[..., 1] + c[1], ijk[..., 2] + c[2],
                           jnp.asarray(seed, jnp.int32))
  return out


def fbm(points, octaves=4, seed=0):
  """Fractal sum of `octaves` value noises, each twice the frequency and half the amplitude.
  points: float32 [..., 3] in lattice units; seed: int or int32 [...]. Returns float32 [...] in
  [0, 1)."""
  total, amp, norm = 0.0, 1.0, 0.0
  for k in range(octaves):
    # 1.7 shifts each octave's lattice off the others' so that their cell corners do not align.
    total = total + amp * value_noise(points * (2.0 ** k) + 1.7 * k, seed * 31 + k)
    norm, amp = norm + amp, amp * 0.5
  return total / norm


def face_chart(points, normals):
  """Per-face 2D coordinates: float32 [..., 2], the two world axes across the normal's dominant
  axis (x-faces -> (y, z), y-faces -> (x, z), z-faces -> (x, y)), and that axis: int32 [...]."""
  axis = jnp.argmax(jnp.abs(normals), axis=-1)
  x, y, z = points[..., 0], points[..., 1], points[..., 2]
  u = jnp.where(axis == 0, y, x)
  v = jnp.where(axis == 2, y, z)
  return jnp.stack([u, v], -1), axis


def glyph_ink(uv, line_height, seed, face):
  """Coverage (0 or 1) of glyph marks on a 2D chart. uv: float32 [..., 2]; line_height: float32
  [...], height of a line; seed, face: int32 [...] (each face of a material has its own text).
  Returns float32 [...].

  Cells are 5/7 of a line wide; every line is shifted by a random fraction of a cell, each cell
  holds a random glyph of `GLYPHS` (one in five is a space), drawn in 3 x 5 of its 7 x 7 dots.
  """
  width = line_height * 5.0 / 7.0
  row = jnp.floor(uv[..., 1] / line_height).astype(jnp.int32)
  shift = hash01(row, face, seed + 7)
  u = uv[..., 0] / width + shift
  col = jnp.floor(u).astype(jnp.int32)
  # Position inside the cell in dots: 1 dot of margin left and right, 1 above and below.
  du = (u - jnp.floor(u)) * 5.0 - 1.0
  dv = (1.0 - (uv[..., 1] / line_height - row)) * 7.0 - 1.0  # 0 at the top row of the glyph
  inside = (du >= 0.0) & (du < 3.0) & (dv >= 0.0) & (dv < 5.0)
  pick = hash01(row, col, face, seed)
  glyph = jnp.minimum((pick * 1.25 * len(_FONT)).astype(jnp.int32), len(_FONT))  # == len: space
  bit = jnp.asarray(GLYPHS)[jnp.minimum(glyph, len(_FONT) - 1),
                            jnp.clip(dv, 0, 4).astype(jnp.int32),
                            jnp.clip(du, 0, 2).astype(jnp.int32)]
  return jnp.where(inside & (glyph < len(_FONT)), bit, 0.0)


def stripes(points, period, axis, warp, seed):
  """Coverage (0 or 1) of noise-warped stripes, half of each period wide. points: float32
  [..., 3]; period, warp: float32 [...] (period > 0); axis: float32 [..., 3] unit; seed: int32
  [...]. Returns float32 [...]."""
  bend = warp * fbm(points * (2.0 / period[..., None]), 2, seed + 101)
  phase = jnp.sum(points * axis, -1) / period + bend
  return (phase - jnp.floor(phase) < 0.5).astype(jnp.float32)


def table(materials):
  """Per-material texture parameters: dict of float32/int32 numpy arrays [M, ...] (`Texture`
  fields, zeros where a material has no texture) plus 'base', the albedo [M, 3]."""
  textures = [getattr(m, "texture", None) or Texture() for m in materials]
  out = {f.name: np.array([getattr(t, f.name) for t in textures],
                          np.int32 if f.name == "seed" else np.float32)
         for f in dataclasses.fields(Texture)}
  axis = out["stripe_axis"]
  out["stripe_axis"] = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
  out["base"] = np.array([m.albedo for m in materials], np.float32)
  return out


def albedo(materials, index, points, normals):
  """Textured diffuse reflectance of surface points. materials: sequence of `Material` (with an
  optional `texture`); index: int [...], each point's material; points, normals: float32
  [..., 3]. Returns float32 [..., 3] in [0, 1].

  Every texture is evaluated once for all points with its material's parameters gathered per
  point (one pass, whatever the number of materials); a switched-off part multiplies by 0.
  """
  p = {k: jnp.asarray(v)[index] for k, v in table(materials).items()}
  points = jnp.asarray(points, jnp.float32)
  normals = jnp.asarray(normals, jnp.float32)
  out = p["base"] * (1.0 - p["noise"] * fbm(points * p["noise_scale"][..., None], 4,
                                             p["seed"]))[..., None]
  has = lambda k: p[k] > 0.0
  period = jnp.where(has("stripes"), p["stripes"], 1.0)  # 1: any finite period for unused lanes
  band = stripes(points, period, p["stripe_axis"], p["stripe_warp"], p["seed"]) * has("stripes")
  out = _paint(out, band, p["stripe_color"])
  uv, axis = face_chart(points, normals)
  positive = jnp.take_along_axis(normals, axis[..., None], -1)[..., 0] > 0.0
  height = jnp.where(has("glyphs"), p["glyphs"], 1.0)  # 1: any finite size for unused lanes
  ink = glyph_ink(uv, height, p["seed"], 2 * axis + positive) * has("glyphs")  # 6 faces, 6 texts
  return _paint(out, ink, p["glyph_color"])


def _paint(rgb, coverage, color):
  """Blend color: float32 [..., 3] over rgb: float32 [..., 3] with coverage: float32 [...]."""
  return rgb + coverage[..., None] * (color - rgb)
