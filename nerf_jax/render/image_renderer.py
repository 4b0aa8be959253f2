"""Rendering images: any number of rays in fixed-size padded chunks (no recompiles, bounded
memory), on the plain path (renderer.RayRenderer.render) or, for models that allow it, with
empty-space skipping and early ray termination (empty_space.py).

A draw function takes `rays.Rays` with any batch shape `...` and a background RGB and returns
a numpy dict rgb float32 [..., 3], depth float32 [...], acc float32 [...].

The chunk (rays per call) is config.render.chunk, or with DEVICE_CHUNK (0) sized from the
device's memory (`device_chunk`): a GPU gets calls as large as a share of its free memory holds,
a CPU (which reports no memory) today's cache-sized default.
"""

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.render import compositing, empty_space, renderer
from nerf_jax.samplers import placement, spacing, visual_hull
from nerf_jax.cameras.rays import Rays


DEVICE_CHUNK = 0  # render.chunk: rays per call sized from the device's memory (device_chunk)
FALLBACK_CHUNK = 4096  # the chunk where the device reports no memory (a CPU): today's default
MEMORY_SHARE = 0.25  # share of the device's free memory one render call may take (unmeasured)
MIN_CHUNK, MAX_CHUNK = 2 ** 10, 2 ** 16  # bounds of a device-sized chunk (the padding of small
# renders grows with the chunk: an 800 x 800 frame is 10 calls of 2^16 rays; unmeasured)
PROBE_RAYS = 2 ** 10  # rays of the compiled call whose memory analysis gives a ray's bytes


@dataclasses.dataclass(frozen=True)
class ImageSettings:
  """How whole images are rendered (config.render; the march_* fields: empty_space.py)."""
  chunk: int = FALLBACK_CHUNK  # rays per jitted render call; DEVICE_CHUNK: device-sized
  march: bool = True  # skip empty space and stop at opaque surfaces where the model allows
  march_grid: int = 48  # cells per side of the skip grid computed from the trained density
  march_threshold: float = 0.1  # density (per scene unit) below which a cell is skipped
  march_probes: int = 4  # skip-grid probes per cell side
  march_group: int = 16  # samples per ray offered in each marching round
  min_transmittance: float = 1e-4  # a ray stops once less light than this gets through
  num_samples: int = 0  # samples per ray (coarse pass) when rendering; 0 = the renderer's own


def make_chunk_renderer(ray_renderer):
  """A jitted deterministic renderer for one fixed-size chunk of rays.

  ray_renderer: renderer.RayRenderer. Returns fn(variables, rays: Rays [C], background float32
  [3]) -> dict of rgb [C, 3], depth [C], acc [C] (variables: see renderer.py).
  """
  @jax.jit
  def render_chunk(variables, rays, background):
    out = renderer.final(ray_renderer.render(variables, rays, key=None, background=background))
    return {k: out[k] for k in ("rgb", "depth", "acc")}
  return render_chunk


def render_image(render_chunk, variables, rays, background=(0.0, 0.0, 0.0),
                 chunk=ImageSettings.chunk):
  """Render `rays` (Rays [...]) with `render_chunk` (from `make_chunk_renderer`) in chunks of
  `chunk` rays. background: RGB. Returns numpy dict rgb [..., 3], depth [...], acc [...]."""
  num_rays, flat = _padded(rays, chunk)
  background = jnp.asarray(background, jnp.float32)
  pieces = [render_chunk(variables, _rows(flat, i, chunk), background)
            for i in range(0, len(flat.origins), chunk)]
  return _joined(pieces, num_rays, rays.shape)


def _padded(rays, chunk):
  """(num_rays, Rays [P] as numpy): `rays` flattened, P the next multiple of `chunk`. Padding
  rays are copies of ray 0, so they are as well-behaved as a real ray."""
  num_rays = int(np.prod(rays.shape))
  padded = -(-num_rays // chunk) * chunk

  def pad(a):
    a = np.asarray(a, np.float32).reshape(num_rays, *a.shape[len(rays.shape):])
    return np.concatenate([a, np.repeat(a[:1], padded - num_rays, axis=0)])
  return num_rays, jax.tree_util.tree_map(pad, rays)


def _rows(rays, start, chunk):
  return jax.tree_util.tree_map(lambda a: a[start:start + chunk], rays)


def _joined(pieces, num_rays, batch_shape):
  """Per-chunk output dicts -> one numpy dict with leading shape batch_shape (padding dropped)."""
  out = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs)[:num_rays], *pieces)
  return {k: v.reshape(*batch_shape, *v.shape[1:]) for k, v in out.items()}


def marches(ray_renderer, settings):
  """Whether rendering skips empty space and stops at opaque surfaces.

  `settings.march` applies to single-pass renderers sampling a scene box (scene_bound > 0) with
  plain stratified samples (`Sampler.marchable`); any other renderer renders on the plain path.
  """
  return bool(settings.march and ray_renderer.num_fine_samples == 0
              and ray_renderer.sampler.marchable)


def device_memory(device=None):
  """Bytes `device` (default: the first jax device) can still allocate: its allocator's limit
  less what is in use; None where the backend reports no memory (a CPU)."""
  stats = (device or jax.devices()[0]).memory_stats()
  if not stats or "bytes_limit" not in stats:
    return None
  return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))


def bytes_per_ray(ray_renderer, variables, probe=PROBE_RAYS):
  """Device bytes one ray of a plain render call takes, from XLA's memory analysis of the chunk
  renderer compiled for `probe` rays (its temporaries, outputs and rays, over `probe`); None
  where the backend gives no analysis. Marching queries at most the samples the plain path
  queries per ray, so this bounds its calls too. Compiles once; runs nothing."""
  _, rays = _padded(_probe_ray(ray_renderer), probe)
  lowered = make_chunk_renderer(ray_renderer).lower(variables, rays, jnp.zeros(3, jnp.float32))
  stats = lowered.compile().memory_analysis()
  if stats is None:
    return None
  ray_bytes = sum(a.nbytes for a in jax.tree_util.tree_leaves(rays))
  return (stats.temp_size_in_bytes + stats.output_size_in_bytes + ray_bytes) / probe


def sized_chunk(free_bytes, ray_bytes):
  """Rays per call that fit MEMORY_SHARE of `free_bytes` at `ray_bytes` bytes per ray: the
  largest power of two that does, within [MIN_CHUNK, MAX_CHUNK]."""
  fits = MEMORY_SHARE * free_bytes / max(ray_bytes, 1.0)
  return int(min(max(2 ** math.floor(math.log2(max(fits, 1.0))), MIN_CHUNK), MAX_CHUNK))


def device_chunk(ray_renderer, variables, free_bytes=None):
  """The chunk of render.chunk = DEVICE_CHUNK: `sized_chunk` of the device's free memory
  (`device_memory`, or `free_bytes` when given) and of a ray's bytes (`bytes_per_ray`), or
  FALLBACK_CHUNK where the device reports no memory (a CPU: today's default, unchanged).
  Prints one line saying which."""
  free = device_memory() if free_bytes is None else free_bytes
  ray_bytes = None if free is None else bytes_per_ray(ray_renderer, variables)
  if ray_bytes is None:
    print(f"render chunk: {FALLBACK_CHUNK} rays per call (the device reports no memory)",
          flush=True)
    return FALLBACK_CHUNK
  chunk = sized_chunk(free, ray_bytes)
  print(f"render chunk: {chunk} rays per call ({MEMORY_SHARE:.0%} of {free / 2 ** 30:.2f} GiB "
        f"free at {ray_bytes / 2 ** 10:.1f} KiB per ray)", flush=True)
  return chunk


class Draw:
  """A draw function: draw(rays, background=(0, 0, 0)) -> numpy dict rgb [..., 3], depth [...],
  acc [...] of Rays [...]; and what it compiles.

  draw.compile_steps() -> iterator: compiles the shapes a call may need, one at a time,
  smallest first, yielding after each the most rays a call may now hold without compiling
  anything (math.inf after the last step). draw.chunk: the rays each call is padded to.
  """

  def __init__(self, draw, compile_steps, chunk):
    self._draw, self.compile_steps, self.chunk = draw, compile_steps, chunk

  def __call__(self, rays, background=(0.0, 0.0, 0.0)):
    return self._draw(rays, background)


def make_image_renderer(ray_renderer, settings, free_bytes=None):
  """fn(variables) -> Draw, rendering Rays [...] in chunks of `settings.chunk` rays.

  ray_renderer: renderer.RayRenderer. settings: ImageSettings. The plain path
  (`make_chunk_renderer` + `render_image`) or, where `marches`, the marching one
  (empty_space.py: the same samples, the field queried only where they matter); the skip grid
  of the marching path is computed once per call with new variables. With settings.chunk =
  DEVICE_CHUNK the chunk is sized at the first call (`device_chunk`, from `free_bytes` when
  given, else the device's) and kept for later ones. ValueError for a negative chunk.
  """
  if settings.chunk < 0:
    raise ValueError(f"config.render.chunk={settings.chunk}: use a positive count of rays per "
                     f"render call, or {DEVICE_CHUNK} to size it from the device's memory")
  ray_renderer = with_samples(ray_renderer, settings.num_samples)
  if settings.chunk != DEVICE_CHUNK:
    return _binder(ray_renderer, settings)
  sized = {}

  def bind(variables):
    if not sized:
      chunk = device_chunk(ray_renderer, variables, free_bytes)
      sized["bind"] = _binder(ray_renderer, dataclasses.replace(settings, chunk=chunk))
    return sized["bind"](variables)
  return bind


def _binder(ray_renderer, settings):
  """`make_image_renderer`'s fn(variables) -> Draw for a positive settings.chunk."""
  if not marches(ray_renderer, settings):
    render_chunk = make_chunk_renderer(ray_renderer)

    def bind(variables):
      # Parameters go to the device once, not with every chunk (restored ones are numpy).
      draw = functools.partial(render_image, render_chunk, jax.device_put(variables),
                               chunk=settings.chunk)

      def compile_steps():  # every call is padded to one chunk: one shape
        draw(_probe_ray(ray_renderer))
        yield math.inf
      return Draw(draw, compile_steps, settings.chunk)
    return bind
  return _Marcher(ray_renderer, settings).bind


def with_samples(ray_renderer, num_samples):
  """ray_renderer drawing `num_samples` samples per ray (its coarse pass); itself for 0.

  A field trained on jittered samples has learnt the integral they estimate on average; a
  deterministic render with more samples estimates it with less error (configs/detail.py:
  32 in training, 64 in renders, docs/quality_per_second.md)."""
  if not num_samples or num_samples == ray_renderer.sampler.num_samples:
    return ray_renderer
  return dataclasses.replace(ray_renderer, sampler=dataclasses.replace(
      ray_renderer.sampler, num_samples=num_samples))


def _probe_ray(ray_renderer):
  """One ray, Rays [1] (numpy), to compile with: its values do not matter, only its kind (with
  a radius where `ray_renderer`'s field reads cones, as the rays it will draw)."""
  ones = np.ones((1,), np.float32)
  direction = np.array([[0.0, 0.0, -1.0]], np.float32)
  rays = Rays(np.zeros((1, 3), np.float32), direction, direction, ones, 2.0 * ones)
  return rays.replace(radii=1e-3 * ones) if ray_renderer.field.cones else rays


class _Marcher:
  """The jitted pieces of empty_space.py for one renderer and settings (compiled once)."""

  def __init__(self, ray_renderer, settings):
    self.settings, self.ray_renderer = settings, ray_renderer
    rs, field = ray_renderer.sampler, ray_renderer.field

    def query(params, points, viewdirs, per_sample=None):
      """The field at single samples [B]; a field of cones reads their frustums too."""
      if per_sample is None:
        return field.at_points(params["coarse"], points, viewdirs)
      rgb, sigma = field.query(params["coarse"], points[:, None], viewdirs,
                               per_sample=renderer.with_sample_axis(per_sample))
      return rgb[:, 0], sigma[:, 0]
    self.skip_grid = jax.jit(lambda params: empty_space.skip_grid(
        field.density(params["coarse"]), settings.march_grid, rs.scene_bound,
        settings.march_threshold, settings.march_probes))
    self.query_round = empty_space.make_query_round(query)

    @jax.jit
    def plan(mask, hull, rays):
      """(t, t_world, points, occupied, rank, per_sample): the plain path's edges t (z-depth)
      and the same edges in world length (for the stop test), float32 [C, S + 1]; where the
      field is queried, float32 [C, S, 3]; occupied and rank as in empty_space.occupied_ranks
      of the samples' midpoints, with a visual hull (renderer.hull_of, or None) the samples
      outside it left out as the plain path gives them no density. A field of cones is
      queried, as on the plain path (RayRenderer._shade), at its frustums' means with
      per_sample (Field.cone_inputs, deterministic); else per_sample is None."""
      t = rs.stratified(rays)
      points = placement.points(rays, spacing.midpoints(t))
      keep = None if hull is None else visual_hull.gate(hull[0], points, hull[1]) > 0
      occupied, rank = empty_space.occupied_ranks(mask, points, rs.scene_bound, keep)
      per_sample = None
      if field.cones:
        points, per_sample = field.cone_inputs(rays, t[..., :-1], t[..., 1:])
      return t, placement.world_t(t, rays), points, occupied, rank, per_sample

    @jax.jit
    def finish(sigma, rgb, t, rays, background):
      out = compositing.composite(rgb, placement.per_unit_t(sigma, rays), t, background)
      return {"rgb": out["rgb"], "depth": renderer.empty_depth_is_far(out, rays.far),
              "acc": out["acc"]}

    self.plan, self.finish = plan, finish

  def bind(self, variables):
    """The Draw of `make_image_renderer` for `variables`."""
    params = jax.device_put(variables["params"])  # once, not with every query
    grids = (self.skip_grid(params),  # plan's mask and hull
             renderer.hull_of(variables, self.ray_renderer.sampler.scene_bound))
    return Draw(functools.partial(self.draw, params, grids),
                functools.partial(self.compile_steps, params, grids), self.settings.chunk)

  def compile_steps(self, params, grids):
    """Draw.compile_steps: the per-chunk functions, then the query round at every buffer size,
    called as `draw` calls them. A call of n rays selects at most min(n, chunk)·g samples per
    round (g samples of each ray: the group, or all S when fewer)."""
    rc, chunk = self.settings, self.settings.chunk
    _, part = _padded(_probe_ray(self.ray_renderer), chunk)
    t, t_world, points, occupied, rank, per_sample = self.plan(*grids, part)
    sigma = jnp.zeros(occupied.shape, jnp.float32)
    rgb = jnp.zeros((*occupied.shape, 3), jnp.float32)
    depth = jnp.zeros(occupied.shape[:1], jnp.float32)
    empty_space.select_round(occupied, rank, depth, np.arange(chunk) < 1, 0,
                             empty_space.max_optical_depth(rc.min_transmittance), rc.march_group)
    self.finish(sigma, rgb, t, part, jnp.asarray(np.zeros(3), jnp.float32))
    group = min(rc.march_group, occupied.shape[1])
    sizes = empty_space.buffer_sizes(chunk * group)
    for size in sizes:
      index = np.full(size, sigma.size, np.int32)  # all padding: nothing is written
      sigma, rgb, depth = self.query_round(params, t_world, points, part.viewdirs, index, sigma,
                                           rgb, per_sample)
      yield math.inf if size == sizes[-1] else size // group

  def draw(self, params, grids, rays, background=(0.0, 0.0, 0.0)):
    rc, chunk = self.settings, self.settings.chunk
    num_rays, flat = _padded(rays, chunk)
    live = np.arange(len(flat.origins)) < num_rays  # padding rays query nothing
    background = jnp.asarray(background, jnp.float32)
    pieces = []
    for i in range(0, len(flat.origins), chunk):
      part = _rows(flat, i, chunk)
      t, t_world, points, occupied, rank, per_sample = self.plan(*grids, part)
      sigma, rgb, _ = empty_space.march(self.query_round, params, t_world, points,
                                        part.viewdirs, occupied, rank, live[i:i + chunk],
                                        rc.march_group, rc.min_transmittance, per_sample)
      pieces.append(self.finish(sigma, rgb, t, part, background))
    return _joined(pieces, num_rays, rays.shape)
