"""Jitted float32 ground truth of opaque scenes, with supersampled (anti-aliased) pixels.

The fast path for large textured scenes (`Scene.supersample > 1`, e.g. 'detail': 100 views of
400 x 400 pixels, 9 rays each). It computes what `nerf_jax.data.scenes.simulator` computes for
scenes without fog or shadows (first opaque hit in [near, far], textured Lambertian albedo plus
Blinn-Phong), in float32 with the cancellation-free intersections of `raycast`.

Supersampling, as a renderer such as Blender's does: pixel (i, j), whose centre ray is that of
`cameras.rays.get_rays` (through i + pixel_center, j + pixel_center), is covered by an s x s
grid of rays at offsets ((k + 0.5) / s - 0.5) pixels around the centre ray. Per pixel:
  rgb   — mean of the subsamples' colours composited on the background (anti-aliased);
  acc   — exact coverage: the fraction of subsamples that hit a surface (fractional on edges);
  depth — the exact z-depth of the centre ray's hit (far if the centre ray misses, even where
          acc > 0): a depth averaged across an edge would be a depth of no surface.
For odd s the centre ray is one of the subsamples.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.backend import precision
from nerf_jax.data.scenes import raycast, textures


def _unit(v):
  return v / jnp.linalg.norm(v, axis=-1, keepdims=True)


def groups(scene, max_size=16):
  """Object indices in culling groups: runs of consecutive objects of one shape type, at most
  `max_size` long (scenes list nearby thin parts together). Returns a list of lists of int."""
  out = []
  for k, obj in enumerate(scene.objects):
    last = out[-1] if out else None
    if last and type(scene.objects[last[0]].shape) is type(obj.shape) and len(last) < max_size:
      last.append(k)
    else:
      out.append([k])
  return out


def bounding_sphere(shapes):
  """(center: float64 [3], radius: float) of a sphere holding every shape."""
  parts = []
  for s in shapes:
    if isinstance(s, raycast.Rod):
      a, b = np.asarray(s.start, np.float64), np.asarray(s.end, np.float64)
      parts.append((0.5 * (a + b), 0.5 * np.linalg.norm(b - a) + s.radius))
    elif hasattr(s, "size"):  # Box
      parts.append((np.asarray(s.center, np.float64), 0.5 * np.linalg.norm(s.size)))
    elif hasattr(s, "height"):  # Cylinder
      parts.append((np.asarray(s.center, np.float64), np.hypot(s.radius, 0.5 * s.height)))
    else:  # Sphere
      parts.append((np.asarray(s.center, np.float64), s.radius))
  center = np.mean([c for c, _ in parts], 0)
  return center, max(np.linalg.norm(c - center) + r for c, r in parts)


def _any_near(center, radius, origins, directions):
  """Whether any ray passes within `radius` of `center` (bool scalar): a cheap test that lets a
  chunk skip a group's intersections."""
  oc = origins - jnp.asarray(center, jnp.float32)
  d2 = jnp.sum(directions * directions, -1)
  t0 = jnp.maximum(-jnp.sum(oc * directions, -1) / d2, 0.0)
  q = oc + t0[..., None] * directions
  return jnp.any(jnp.sum(q * q, -1) <= (1.001 * radius) ** 2)  # 1.001: float32 slack


def first_hit(scene, origins, directions, near, far):
  """The nearest object whose solid overlaps [near, far]. origins, directions: float32 [..., 3].
  Returns t: float32 [...] (inf where none), index: int32 [...] (-1), normal: float32 [..., 3].

  Each culling group (`groups`) is intersected at once (`raycast.intersect_group`), and only if
  some ray of the batch passes through its bounding sphere (`lax.cond` skips it otherwise:
  most chunks of pixels of an image see few of the thin rods).
  """
  shape = origins.shape[:-1]
  best = (jnp.full(shape, jnp.inf, jnp.float32), jnp.full(shape, -1, jnp.int32),
          jnp.zeros_like(origins))
  for members in groups(scene):
    shapes = [scene.objects[k].shape for k in members]
    center, radius = bounding_sphere(shapes)

    def group_hit(rays, shapes=shapes, members=members):
      t_in, t_out, n = raycast.intersect_group(shapes, *rays)  # [..., K]
      t = jnp.maximum(t_in, near)
      t = jnp.where((t_in <= t_out) & (t_out >= near) & (t <= far), t, jnp.inf)
      k = jnp.argmin(t, -1)
      return (jnp.take_along_axis(t, k[..., None], -1)[..., 0],
              jnp.asarray(members, jnp.int32)[k],
              jnp.take_along_axis(n, k[..., None, None], -2)[..., 0, :])

    found = jax.lax.cond(_any_near(center, radius, origins, directions), group_hit,
                         lambda rays: best, (origins, directions))
    closer = found[0] < best[0]
    best = tuple(jnp.where(closer.reshape(closer.shape + (1,) * (a.ndim - closer.ndim)), a, b)
                 for a, b in zip(found, best))
  return best


def shade(scene, index, points, normals, viewdirs):
  """Colour of surface points: textured Lambertian + (if declared) Blinn-Phong, as
  `simulator.diffuse` and `simulator.specular` without shadows. index: int32 [...] (>= 0);
  points, normals, viewdirs (unit, from the camera): float32 [..., 3]. Returns float32 [..., 3]."""
  mats = [o.material for o in scene.objects]
  light = scene.light
  to_light = _unit(jnp.asarray(light.direction, jnp.float32))
  albedo = textures.albedo(mats, index, points, normals)
  cosine = precision.matmul(normals, to_light)
  rgb = albedo * (jnp.asarray(light.ambient, jnp.float32)
                  + jnp.maximum(cosine, 0.0)[..., None] * jnp.asarray(light.color, jnp.float32))
  if scene.effects.view_dependent:
    strength = jnp.asarray([m.specular for m in mats], jnp.float32)[index]
    shininess = jnp.asarray([m.shininess for m in mats], jnp.float32)[index]
    half = _unit(to_light - viewdirs)
    power = jnp.maximum(jnp.sum(normals * half, -1), 0.0) ** shininess
    spec = strength * power * (cosine > 0.0)  # no highlight on the unlit side
    rgb = rgb + spec[..., None] * jnp.asarray(light.color, jnp.float32)
  return jnp.clip(rgb, 0.0, 1.0)


def trace(scene, origins, directions, near, far):
  """One ray each. origins, directions: float32 [..., 3]. Returns (emitted rgb: float32
  [..., 3], 0 on a miss; t: float32 [...], inf on a miss; hit: bool [...])."""
  t, index, normal = first_hit(scene, origins, directions, near, far)
  hit = jnp.isfinite(t)

  def colour(_):
    points = origins + jnp.where(hit, t, 0.0)[..., None] * directions
    rgb = shade(scene, jnp.maximum(index, 0), points, normal, _unit(directions))
    return jnp.where(hit[..., None], rgb, 0.0)

  rgb = jax.lax.cond(jnp.any(hit), colour, lambda _: jnp.zeros_like(origins), None)
  return rgb, t, hit


trace_rays = jax.jit(trace, static_argnums=0)  # `trace`, compiled once per scene and ray shape


def _check(scene):
  if scene.medium is not None or scene.effects.shadows:
    raise ValueError(f"scene {scene.name!r}: the tracer renders neither fog nor shadows; "
                     "use nerf_jax.data.scenes.simulator")


def _subsamples(s):
  """Offsets of the rays of a pixel from its centre ray, in pixels: ox, oy: float32 [S]; their
  weights in the pixel's mean: float32 [S] (1/s^2 each); and the index of the centre ray. An
  even s has no ray at the centre: one is appended with weight 0 (traced for its depth only)."""
  offsets = (np.arange(s) + 0.5) / s - 0.5
  ox, oy = [a.reshape(-1) for a in np.meshgrid(offsets, offsets, indexing="xy")]
  weight = np.full(s * s, 1.0 / (s * s))
  if s % 2 == 0:
    ox, oy, weight = np.append(ox, 0.0), np.append(oy, 0.0), np.append(weight, 0.0)
  centre = s * s // 2 if s % 2 else s * s
  return ox.astype(np.float32), oy.astype(np.float32), weight.astype(np.float32), centre


@functools.partial(jax.jit, static_argnums=(0, 1))
def _render_pixels(scene, supersample, c2w, row, col, height, width, focal, pixel_center, near,
                   far):
  """Pixels (row, col): int32 [P] of cameras c2w: float32 [P, 3, 4] (each pixel's own; shapes
  fixed by the chunk, so one compilation per scene and s serves every image size and view
  count). height, width: int32 scalars; focal, pixel_center, near, far: float32 scalars.
  Returns rgb float32 [P, 3], depth float32 [P], acc float32 [P] (see the module doc)."""
  ox, oy, weight, centre = _subsamples(supersample)
  x = (col[:, None] + pixel_center + ox - 0.5 * width) / focal
  y = -(row[:, None] + pixel_center + oy - 0.5 * height) / focal
  cam = jnp.stack([x, y, -jnp.ones_like(x)], -1)  # [P, S, 3], camera-space z = -1
  directions = precision.einsum("pij,psj->psi", c2w[:, :3, :3], cam)
  origins = jnp.broadcast_to(c2w[:, None, :3, 3], directions.shape)
  rgb, t, hit = trace(scene, origins, directions, near, far)
  acc = precision.matmul(hit.astype(jnp.float32), weight)
  rgb = precision.einsum("psc,s->pc", rgb, weight)
  rgb = rgb + (1.0 - acc)[:, None] * jnp.asarray(scene.background, jnp.float32)
  t_centre = t[:, centre]
  depth = jnp.where(jnp.isfinite(t_centre), t_centre, far)
  return rgb, depth, acc


def tile_order(num_views, height, width, tile):
  """All pixel ids (int64 [V * H * W], flat over [V, H, W]) ordered tile by tile (tile x tile
  pixels of one view, row-major inside), so that a chunk of pixels is a compact patch."""
  v, j, i = np.meshgrid(np.arange(num_views), np.arange(height), np.arange(width), indexing="ij")
  order = np.lexsort([i.ravel(), j.ravel(), i.ravel() // tile, j.ravel() // tile, v.ravel()])
  return order


def render_images(scene, poses, height, width, focal, pixel_center=0.0, near=2.0, far=6.0,
                  supersample=None, tile=32):
  """Ground truth of many views, in fixed chunks of pixels (one compilation, bounded memory).

  poses: float [V, 4, 4] camera-to-world. focal: float, pixels. supersample: int s (rays per
  pixel s^2) or None (= scene.supersample). tile: int, each jitted call renders tile x tile
  pixels of one image (a compact patch, so that `first_hit` skips the groups it cannot see).
  Returns {'rgb': float32 [V, H, W, 3], 'depth': float32 [V, H, W], 'acc': float32 [V, H, W]}.
  """
  _check(scene)
  poses = np.asarray(poses, np.float32)[:, :3, :4]
  total = len(poses) * height * width
  s = int(scene.supersample if supersample is None else supersample)
  scalars = (jnp.int32(height), jnp.int32(width),
             *(jnp.float32(a) for a in (focal, pixel_center, near, far)))
  order = tile_order(len(poses), height, width, tile)
  chunk = tile * tile
  padded = np.concatenate([order, np.full(-total % chunk, order[-1])])
  view, pixel = np.divmod(padded, height * width)
  row, col = (a.astype(np.int32) for a in np.divmod(pixel, width))
  outs = [_render_pixels(scene, s, poses[view[k:k + chunk]], row[k:k + chunk], col[k:k + chunk],
                         *scalars) for k in range(0, len(padded), chunk)]  # async dispatch
  shape = (len(poses), height, width)
  result = {}
  for name, parts in zip(("rgb", "depth", "acc"), zip(*outs)):
    flat = np.concatenate(jax.device_get(parts))[:total]
    result[name] = np.empty_like(flat)
    result[name][order] = flat
  return {"rgb": result["rgb"].reshape(*shape, 3), "depth": result["depth"].reshape(shape),
          "acc": result["acc"].reshape(shape)}
