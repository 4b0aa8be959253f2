"""A disk cache of rendered ground truth, for scenes too large to render at every load.

The 'detail' scene's 100 views of 400 x 400 pixels (9 rays each) take minutes on a 2-core CPU;
its arrays (320 MB) load in about a second. An entry is keyed by everything the pixels depend
on: the scene's full description (every object, material and texture), the cameras, the render
arguments, and the source code of the modules that render it, so that editing a texture or the
tracer never serves stale pixels.

The cache lives in $NERF_JAX_CACHE (default ~/.cache/nerf_jax/scenes); NERF_JAX_CACHE=off
disables it. Jobs smaller than `MIN_RAYS` are never cached (they render faster than a read).
"""

import hashlib
import os

import numpy as np

from nerf_jax.data.scenes import raycast, textures, tracer

MIN_RAYS = 1 << 23  # ~8M rays: about 20 s of tracing on a 2-core CPU, more than a cache read
_SOURCES = (raycast, textures, tracer)  # the code the pixels depend on


def directory():
  """The cache directory, or None when disabled."""
  path = os.environ.get("NERF_JAX_CACHE", os.path.join("~", ".cache", "nerf_jax", "scenes"))
  return None if path == "off" else os.path.expanduser(path)


def key(scene, poses, **render_args):
  """Hex digest of the scene, poses (float [V, 4, 4]), render arguments and renderer source."""
  h = hashlib.sha256(repr(scene).encode())
  h.update(np.ascontiguousarray(poses, np.float32).tobytes())
  h.update(repr(sorted(render_args.items())).encode())
  for module in _SOURCES:
    with open(module.__file__, "rb") as f:
      h.update(f.read())
  return h.hexdigest()[:24]


def render_images(scene, poses, height, width, focal, pixel_center=0.0, near=2.0, far=6.0):
  """`tracer.render_images`, read from / written to the cache when large. Same returns."""
  args = dict(height=height, width=width, focal=float(focal), pixel_center=float(pixel_center),
              near=float(near), far=float(far))
  rays = len(poses) * height * width * scene.supersample ** 2
  folder = directory()
  if folder is None or rays < MIN_RAYS:
    return tracer.render_images(scene, poses, **args)
  path = os.path.join(folder, f"{scene.name}-{key(scene, poses, **args)}.npz")
  if os.path.isfile(path):
    with np.load(path) as archive:
      return {k: archive[k] for k in ("rgb", "depth", "acc")}
  out = tracer.render_images(scene, poses, **args)
  os.makedirs(folder, exist_ok=True)
  partial = path + f".{os.getpid()}.tmp.npz"  # written whole, then renamed: no torn entries
  np.savez(partial, **out)
  os.replace(partial, path)
  return out
