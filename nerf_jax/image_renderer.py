"""Rendering images: any number of rays in fixed-size padded chunks (no recompiles, bounded
memory), on the plain path (renderer.render_rays) or, for models that allow it, with
empty-space skipping and early ray termination (empty_space.py).

A draw function takes `rays.Rays` with any batch shape `...` and a background RGB and returns
a numpy dict rgb float32 [..., 3], depth float32 [...], acc float32 [...].
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax import compositing, empty_space, field, occupancy, renderer, sampling
from nerf_jax.rays import Rays


def make_chunk_renderer(model, config):
  """A jitted deterministic renderer for one fixed-size chunk of rays.

  Returns fn(params, rays: Rays [C], background float32 [3]) -> dict of rgb [C, 3], depth [C],
  acc [C].
  """
  @jax.jit
  def render_chunk(params, rays, background):
    out = renderer.final(renderer.render_rays(model, params, rays, config, key=None,
                                              background=background))
    return {k: out[k] for k in ("rgb", "depth", "acc")}
  return render_chunk


def render_image(render_chunk, params, rays, background=(0.0, 0.0, 0.0), chunk=4096):
  """Render `rays` (Rays [...]) with `render_chunk` (from `make_chunk_renderer`) in chunks of
  `chunk` rays. background: RGB. Returns numpy dict rgb [..., 3], depth [...], acc [...]."""
  num_rays, flat = _padded(rays, chunk)
  background = jnp.asarray(background, jnp.float32)
  pieces = [render_chunk(params, _rows(flat, i, chunk), background)
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


def marches(config):
  """Whether rendering `config`'s model skips empty space and stops at opaque surfaces.

  `config.render.march` applies to single-pass models sampling a scene box (data.scene_bound >
  0) with plain stratified samples; any other model renders on the plain path.
  """
  return bool(config.render.march and config.data.scene_bound > 0
              and config.num_fine_samples == 0 and not occupancy.enabled(config)
              and not config.data.ndc)


class Draw:
  """A draw function: draw(rays, background=(0, 0, 0)) -> numpy dict rgb [..., 3], depth [...],
  acc [...] of Rays [...]; and what it compiles.

  draw.compile_steps() -> iterator: compiles the shapes a call may need, one at a time,
  smallest first, yielding after each the most rays a call may now hold without compiling
  anything (math.inf after the last step).
  """

  def __init__(self, draw, compile_steps):
    self._draw, self.compile_steps = draw, compile_steps

  def __call__(self, rays, background=(0.0, 0.0, 0.0)):
    return self._draw(rays, background)


def make_image_renderer(model, config):
  """fn(params) -> Draw, rendering Rays [...] in chunks of `config.render.chunk`.

  The plain path (`make_chunk_renderer` + `render_image`) or, where `marches(config)`, the
  marching one (empty_space.py: the same samples, the field queried only where they matter);
  the skip grid of the marching path is computed once per call with new params.
  """
  if not marches(config):
    render_chunk = make_chunk_renderer(model, config)

    def bind(params):
      # Parameters go to the device once, not with every chunk (restored ones are numpy).
      draw = functools.partial(render_image, render_chunk, jax.device_put(params),
                               chunk=config.render.chunk)

      def compile_steps():  # every call is padded to one chunk: one shape
        draw(_probe_ray())
        yield math.inf
      return Draw(draw, compile_steps)
    return bind
  return _Marcher(model, config).bind


def _probe_ray():
  """One ray, Rays [1] (numpy), to compile with: its values do not matter, only its kind."""
  ones = np.ones((1,), np.float32)
  direction = np.array([[0.0, 0.0, -1.0]], np.float32)
  return Rays(np.zeros((1, 3), np.float32), direction, direction, ones, 2.0 * ones)


class _Marcher:
  """The jitted pieces of empty_space.py for one model and config (compiled once, reused)."""

  def __init__(self, model, config):
    self.config = config
    rc, box = config.render, config.data.scene_bound

    def query(params, points, viewdirs):  # [B, 3], [B, 3] -> rgb [B, 3], sigma [B]
      rgb, sigma = field.query(model, params["coarse"], points[:, None, :], viewdirs, config)
      return rgb[:, 0], sigma[:, 0]

    self.skip_grid = jax.jit(lambda params: empty_space.skip_grid(
        field.coarse_density(model, params, config), rc.march_grid, box, rc.march_threshold,
        rc.march_probes))
    self.query_round = empty_space.make_query_round(query)

    @jax.jit
    def plan(mask, rays):
      """(t, t_world, points, occupied, rank): the plain path's edges t (z-depth) and the same
      edges in world length (t·|d|, for the stop test), float32 [C, S + 1]; the rest as in
      empty_space.occupied_ranks."""
      t_near, t_far = renderer.sample_bounds(rays, config)
      t = sampling.stratified(t_near, t_far, config.num_samples, rays.shape, None,
                              lindisp=config.data.lindisp)
      points = (rays.origins[:, None, :]
                + rays.directions[:, None, :] * sampling.midpoints(t)[..., None])
      t_world = t * jnp.linalg.norm(rays.directions, axis=-1)[:, None]
      return (t, t_world, points, *empty_space.occupied_ranks(mask, points, box))

    @jax.jit
    def finish(sigma, rgb, t, rays, background):
      out = compositing.composite(rgb, renderer.per_unit_t(sigma, rays), t, background)
      return {"rgb": out["rgb"], "depth": renderer.empty_depth_is_far(out, rays.far),
              "acc": out["acc"]}

    self.plan, self.finish = plan, finish

  def bind(self, params):
    """The Draw of `make_image_renderer` for `params`."""
    params = jax.device_put(params)  # once, not with every query
    mask = self.skip_grid(params)
    return Draw(functools.partial(self.draw, params, mask),
                functools.partial(self.compile_steps, params, mask))

  def compile_steps(self, params, mask):
    """Draw.compile_steps: the per-chunk functions, then the query round at every buffer size,
    called as `draw` calls them. A call of n rays selects at most min(n, chunk)·g samples per
    round (g samples of each ray: the group, or all S when fewer)."""
    rc, chunk = self.config.render, self.config.render.chunk
    _, part = _padded(_probe_ray(), chunk)
    t, t_world, points, occupied, rank = self.plan(mask, part)
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
                                           rgb)
      yield math.inf if size == sizes[-1] else size // group

  def draw(self, params, mask, rays, background=(0.0, 0.0, 0.0)):
    rc, chunk = self.config.render, self.config.render.chunk
    num_rays, flat = _padded(rays, chunk)
    live = np.arange(len(flat.origins)) < num_rays  # padding rays query nothing
    background = jnp.asarray(background, jnp.float32)
    pieces = []
    for i in range(0, len(flat.origins), chunk):
      part = _rows(flat, i, chunk)
      t, t_world, points, occupied, rank = self.plan(mask, part)
      sigma, rgb, _ = empty_space.march(self.query_round, params, t_world, points,
                                        part.viewdirs, occupied, rank, live[i:i + chunk],
                                        rc.march_group, rc.min_transmittance)
      pieces.append(self.finish(sigma, rgb, t, part, background))
    return _joined(pieces, num_rays, rays.shape)
