"""Exact ground-truth renderer of a `Scene` (numpy float64 inside, float32 out).

It reproduces what a NeRF's compositing over [near, far] converges to (`nerf_jax.rendering`):
  acc   — opacity of the ray inside [near, far]: 1 on an opaque surface, 0 on an empty ray;
  depth — E[t | the ray terminates], t the un-normalised ray parameter (= z-depth); far if acc = 0;
  rgb   — emitted colour + (1 - acc) * background.
Objects are solids: a ray whose near plane starts inside one terminates at `near`.
Only the effects the scene declares are computed (`Scene.effects`).
"""

import jax
import numpy as np

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data.scenes import textures
from nerf_jax.data.scenes.geometry import dot


def diffuse(albedo, normals, light, lit):
  """Lambertian shading. albedo, normals: float64 [R, 3]; lit: float64 [R], 1 where the light
  is not shadowed. Returns float64 [R, 3]."""
  to_light = _unit(np.asarray(light.direction, np.float64))
  cosine = np.maximum(normals @ to_light, 0.0) * lit
  return albedo * (np.asarray(light.ambient) + cosine[:, None] * np.asarray(light.color))


def specular(strength, shininess, normals, viewdirs, light, lit):
  """Blinn-Phong highlight, the only view-dependent term. strength, shininess, lit: float64 [R];
  normals, viewdirs (unit, from the camera): float64 [R, 3]. Returns float64 [R, 3]."""
  to_light = _unit(np.asarray(light.direction, np.float64))
  half = _unit(to_light - viewdirs)
  facing = (normals @ to_light > 0.0) * lit  # no highlight on the unlit side
  power = np.maximum(dot(normals, half), 0.0) ** shininess
  return (strength * power * facing)[:, None] * np.asarray(light.color)


def trace_medium(medium, origins, directions, near, t_stop):
  """Exact emission-absorption of a homogeneous medium along [near, t_stop].

  origins, directions: float64 [R, 3]; t_stop: float64 [R], where the ray ends (far or an opaque
  surface). Returns (acc, rgb, depth_sum, transmittance): float64 [R], [R, 3], [R], [R].

  Per unit of t the extinction is s = sigma * |d|. On the segment [a, b] inside the medium,
  L = b - a and E = exp(-s L); the termination density is p(t) = s exp(-s (t - a)), so
    acc       = int_a^b p(t) dt = 1 - E,
    rgb       = color * (1 - E)                         (constant emission),
    depth_sum = int_a^b t p(t) dt = a (1 - E) + int_0^L u s e^{-s u} du
              = a (1 - E) + (1 - E) / s - L E           (integration by parts),
  and whatever lies behind the segment is seen with transmittance E.
  """
  t_in, t_out, _ = medium.shape.intersect(origins, directions)
  a = np.maximum(t_in, near)
  length = np.maximum(np.minimum(t_out, t_stop) - a, 0.0)
  a = np.where(length > 0.0, a, 0.0)  # a is +-inf on a miss; inf * 0 would be nan
  s = medium.density * np.linalg.norm(directions, axis=-1)
  acc = -np.expm1(-s * length)  # 1 - E without cancellation for thin fog
  trans = np.exp(-s * length)  # E, not 1 - acc: that cancels for thick fog
  depth_sum = a * acc + acc / s - length * trans
  return acc, acc[:, None] * np.asarray(medium.color), depth_sum, trans


def first_hit(objects, origins, directions, near, far):
  """The nearest opaque object whose solid overlaps [near, far] on each ray.

  Returns t: float64 [R] (inf where none), index: int [R] (-1 where none), normal: float64 [R, 3].
  """
  num = len(origins)
  t_hit, index, normal = np.full(num, np.inf), np.full(num, -1), np.zeros((num, 3))
  for k, obj in enumerate(objects):
    t_in, t_out, n = obj.shape.intersect(origins, directions)
    t = np.maximum(t_in, near)
    closer = (t_in <= t_out) & (t_out >= near) & (t <= far) & (t < t_hit)
    t_hit, index = np.where(closer, t, t_hit), np.where(closer, k, index)
    normal = np.where(closer[:, None], n, normal)
  return t_hit, index, normal


def _shadow(scene, points, normals):
  """float64 [R]: 1 where the directional light reaches `points`, else 0."""
  to_light = np.broadcast_to(_unit(np.asarray(scene.light.direction, np.float64)), points.shape)
  start = points + 1e-6 * normals  # leave the surface so that it does not shadow itself
  t, _, _ = first_hit(scene.objects, start, to_light, 0.0, np.inf)
  return np.isinf(t).astype(np.float64)


def surface_rgb(scene, index, points, normals, viewdirs):
  """Colour of the opaque surface points. index: int [R] (>= 0); points, normals, viewdirs
  (unit): float64 [R, 3]. Returns float64 [R, 3] in [0, 1]."""
  mats = [o.material for o in scene.objects]
  lit = _shadow(scene, points, normals) if scene.effects.shadows else np.ones(len(index))
  albedo = _albedo(mats, index, points)
  if any(m.texture is not None for m in mats):  # procedural textures are float32 jax.numpy
    albedo = _textured_albedo(tuple(mats), index, points, normals)
  rgb = diffuse(albedo, normals, scene.light, lit)
  if scene.effects.view_dependent:
    strength = np.array([m.specular for m in mats])[index]
    shininess = np.array([m.shininess for m in mats])[index]
    rgb = rgb + specular(strength, shininess, normals, viewdirs, scene.light, lit)
  return np.clip(rgb, 0.0, 1.0)


def _textured_albedo(materials, index, points, normals):
  """`textures.albedo` of R points as float64 [R, 3], jitted over arrays padded to a power of two
  (at least 1024), so that chunks with different numbers of hits share a few compilations
  instead of compiling every operation for every new R. materials: tuple of Material."""
  num = len(index)
  size = max(1024, 1 << (num - 1).bit_length())
  pad = lambda a: np.concatenate([a, np.zeros((size - num,) + a.shape[1:], a.dtype)])
  out = _jitted_albedo(materials, pad(np.asarray(index, np.int32)),
                       pad(np.asarray(points, np.float32)), pad(np.asarray(normals, np.float32)))
  return np.asarray(out, np.float64)[:num]


_jitted_albedo = jax.jit(textures.albedo, static_argnums=0)


def _albedo(materials, index, points):
  """Diffuse reflectance of surface points: float64 [R, 3]. materials: list of Material;
  index: int [R], each point's material; points: float64 [R, 3]."""
  albedo = np.array([m.albedo for m in materials], np.float64)[index]
  size = np.array([m.checker for m in materials], np.float64)[index]
  if not np.any(size > 0):
    return albedo
  cells = np.floor(points[:, :2] / np.where(size > 0, size, 1.0)[:, None]).sum(-1)
  second = (size > 0) & (np.mod(cells, 2.0) == 1.0)
  return np.where(second[:, None], np.array([m.albedo2 for m in materials])[index], albedo)


def trace_rays(scene, origins, directions, near=2.0, far=6.0, chunk=1 << 16):
  """Ground truth for a batch of rays.

  origins, directions: float [R, 3] (directions un-normalised as in `nerf_jax.cameras.rays`).
  chunk: int, rays per step (cache-sized chunks are ~1.5x faster than one big batch).
  Returns {'rgb': float64 [R, 3], 'depth': float64 [R], 'acc': float64 [R]}.
  """
  origins, directions = np.asarray(origins, np.float64), np.asarray(directions, np.float64)
  outs = [_render_chunk(scene, origins[i:i + chunk], directions[i:i + chunk], near, far)
          for i in range(0, max(len(origins), 1), chunk)]
  return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}


def _render_chunk(scene, origins, directions, near, far):
  """`trace_rays` on float64 [R, 3] rays: the first opaque hit, then the fog in front of it."""
  t_hit, index, normal = first_hit(scene.objects, origins, directions, near, far)
  hit = np.isfinite(t_hit)
  colour = np.zeros_like(origins)
  if hit.any():
    points = origins[hit] + t_hit[hit, None] * directions[hit]
    colour[hit] = surface_rgb(scene, index[hit], points, normal[hit], _unit(directions[hit]))
  t_stop = np.where(hit, t_hit, far)
  if scene.effects.participating_medium:
    acc, rgb, depth_sum, trans = trace_medium(scene.medium, origins, directions, near, t_stop)
  else:
    acc, rgb, depth_sum, trans = (np.zeros(len(origins)), np.zeros_like(origins),
                                  np.zeros(len(origins)), np.ones(len(origins)))
  surface_weight = trans * hit
  acc = acc + surface_weight
  rgb = rgb + surface_weight[:, None] * colour
  depth_sum = depth_sum + surface_weight * np.where(hit, t_hit, 0.0)
  depth = np.where(acc > 0.0, depth_sum / np.maximum(acc, 1e-300), far)  # 1e-300: no 0/0 warning
  rgb = rgb + (1.0 - acc)[:, None] * np.asarray(scene.background, np.float64)
  return {"rgb": rgb, "depth": depth, "acc": acc}


def render_view(scene, c2w, height, width, focal, pixel_center=0.0, near=2.0, far=6.0):
  """Ground-truth image of a pinhole camera, with the rays of `nerf_jax.cameras.rays.get_rays`.

  c2w: float [3, 4] or [4, 4]. Returns {'rgb': float32 [H, W, 3] in [0, 1],
  'depth': float32 [H, W], 'acc': float32 [H, W]}.
  """
  origins, directions = rays_lib.get_rays(height, width, focal, c2w, pixel_center)
  out = trace_rays(scene, np.asarray(origins).reshape(-1, 3),
                    np.asarray(directions).reshape(-1, 3), near, far)
  return {k: v.reshape(height, width, *v.shape[1:]).astype(np.float32) for k, v in out.items()}


def _unit(v):
  return v / np.linalg.norm(v, axis=-1, keepdims=True)
