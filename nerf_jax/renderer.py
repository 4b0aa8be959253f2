"""The per-ray pipeline: sample -> encode -> MLP -> composite, and chunked image rendering.

rays: `rays.Rays` with origins, directions float32 [..., 3].
Outputs of a pass (a dict): rgb float32 [..., 3], depth float32 [...], acc float32 [...],
weights float32 [..., S], t float32 [..., S + 1].
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax import activations, encoding, grid, marching, ndc, occupancy, rendering, sampling
from nerf_jax.rays import Rays, get_rays_intrinsics, safe_normalize


def camera_rays(height, width, intrinsics, pose, config):
  """The rays the field is queried along for one camera.

  Returns (origins, directions, viewdirs), each float32 [height, width, 3]. viewdirs are the unit
  world directions (what the view branch sees); with `config.data.ndc` origins and directions are
  in normalized device coordinates (see ndc.py) and the ray parameter runs over [0, 1].
  """
  origins, directions = get_rays_intrinsics(height, width, intrinsics, pose,
                                            config.data.pixel_center)
  viewdirs = safe_normalize(directions)
  if config.data.get("ndc", False):
    fx, fy = intrinsics[0], intrinsics[1]
    origins, directions = ndc.ndc_rays(origins, directions, fx, width, height, near=1.0,
                                       focal_y=fy)
  return origins, directions, viewdirs


def network_names(config):
  """Parameter groups: a fine network exists only with hierarchical sampling and unshared nets."""
  if config.num_fine_samples > 0 and not config.model.shared_fine:
    return ("coarse", "fine")
  return ("coarse",)


def init_params(model, config, key):
  """Parameters {'coarse': ..., ['fine': ...], ['occupancy': float32 [R, R, R]]} for `model`.

  The occupancy grid starts at zeros, which counts as occupied everywhere (see occupancy.py).
  """
  check_occupancy_config(config)
  pos_width = 3 if _uses_grid(config) else encoding.encoded_width(3, config.pos_encode_dims)
  pos = jnp.zeros((1, pos_width), jnp.float32)
  dirs = jnp.zeros((1, encoding.encoded_width(3, config.dir_encode_dims)), jnp.float32)
  keys = jax.random.split(key, 2)
  params = {name: model.init(k, pos, dirs)["params"]
            for name, k in zip(network_names(config), keys)}
  if uses_occupancy(config):
    res = config.occupancy.resolution
    params["occupancy"] = jnp.zeros((res, res, res), jnp.float32)
  return params


def uses_occupancy(config):
  """Whether `config` samples through an occupancy grid (older configs have no such field)."""
  occ = config.get("occupancy", None)
  return bool(occ is not None and occ.enabled)


def check_occupancy_config(config):
  """ValueError naming the field when `config.occupancy.enabled` cannot work with the rest."""
  if not uses_occupancy(config):
    return
  if config.data.get("scene_bound", 0.0) <= 0:
    raise ValueError("config.occupancy.enabled needs config.data.scene_bound > 0 (the grid "
                     "covers that box)")
  if config.num_fine_samples > 0:
    raise ValueError("config.occupancy.enabled and config.num_fine_samples > 0 cannot be "
                     "combined: the occupancy grid already places the samples; set one of them")
  if config.data.get("ndc", False):
    raise ValueError("config.occupancy.enabled does not work with config.data.ndc")


def coarse_density(model, params, config):
  """points float32 [P, 3] -> σ float32 [P] of the coarse network (direction-independent)."""
  def density(points):
    _, sigma = query_field(model, params["coarse"], points[:, None, :], jnp.zeros_like(points),
                           config)
    return sigma[:, 0]
  return density


def occupancy_grid(model, params, config):
  """The occupancy grid of the coarse network's density: float32 [R, R, R] (see occupancy.py)."""
  return occupancy.density_grid(coarse_density(model, params, config),
                                config.occupancy.resolution, config.data.scene_bound)


def _uses_grid(config):
  return config.model.get("encoding", "posenc") == "grid"


def query_field(model, params, points, viewdirs, config, key=None):
  """Colour and density at sample points.

  points: float32 [..., S, 3]. viewdirs: float32 [..., 3] unit directions. key: PRNG key for the
  density noise (None = no noise). Returns rgb float32 [..., S, 3], sigma float32 [..., S].
  """
  if _uses_grid(config):
    pos_features = points  # the grids are the encoding
  else:
    pos_features = encoding.positional_encoding(points, config.pos_encode_dims)
  dir_features = None
  if config.model.view_dependent:
    dirs = jnp.broadcast_to(viewdirs[..., None, :], points.shape)
    dir_features = encoding.positional_encoding(dirs, config.dir_encode_dims)
  rgb, raw_sigma = model.apply({"params": params}, pos_features, dir_features)
  if key is not None and config.model.density_noise > 0:
    # The paper's regulariser: noise on the raw output, before the activation keeps sigma >= 0.
    raw_sigma = raw_sigma + config.model.density_noise * jax.random.normal(key, raw_sigma.shape)
  sigma = activations.density_activation(config.model.density_activation)(raw_sigma)
  return rgb, sigma


def query_field_in_chunks(model, params, points, viewdirs, config, key=None, chunk=0):
  """`query_field` over chunks of `chunk` rays, each rematerialised in the backward pass.

  points: float32 [R, S, 3], viewdirs: float32 [R, 3]. chunk: rays per chunk, dividing R (0, R
  or a non-divisor = one call). A chunk's activations fit in the CPU's cache, and the backward
  pass recomputes them instead of reading them back from memory: about a third more FLOPs for
  less memory traffic. The density noise of chunk c is drawn from fold_in(key, c).
  Returns rgb float32 [R, S, 3], sigma float32 [R, S], equal to `query_field`'s up to rounding.
  """
  num_rays = points.shape[0]
  if not chunk or chunk >= num_rays or num_rays % chunk or points.ndim != 3:
    return query_field(model, params, points, viewdirs, config, key)
  count = num_rays // chunk
  split = lambda a: a.reshape(count, chunk, *a.shape[1:])

  @jax.checkpoint
  def one_chunk(args):
    pts, dirs, index = args
    chunk_key = None if key is None else jax.random.fold_in(key, index)
    return query_field(model, params, pts, dirs, config, chunk_key)

  rgb, sigma = jax.lax.map(one_chunk, (split(points), split(viewdirs), jnp.arange(count)))
  return rgb.reshape(*points.shape[:-1], 3), sigma.reshape(points.shape[:-1])


def _shade(model, params, rays, viewdirs, t, config, background, key):
  """One pass over the intervals `t: float32 [..., S + 1]`."""
  positions = sampling.midpoints(t)
  points = rays.origins[..., None, :] + rays.directions[..., None, :] * positions[..., None]
  rgb, sigma = query_field_in_chunks(model, params, points, viewdirs, config, key,
                                     config.train.get("remat_chunk", 0))
  out = rendering.composite(rgb, sigma, t, background)
  out["t"] = t
  return out


def _shade_occupied(model, params, rays, viewdirs, t_min, t_max, config, background, keys):
  """One pass over the occupied intervals of [t_min, t_max] (float32 [...]); see occupancy.py."""
  oc = config.occupancy
  mask = occupancy.occupied_mask(jax.lax.stop_gradient(params["occupancy"]), oc.threshold)
  starts, ends, valid = occupancy.sample_occupied(
      mask, rays.origins, rays.directions, t_min, t_max, config.data.scene_bound, oc.candidates,
      config.num_samples)
  u = 0.5 if keys[0] is None else jax.random.uniform(keys[0], starts.shape, jnp.float32)
  positions = starts + (ends - starts) * u
  points = rays.origins[..., None, :] + rays.directions[..., None, :] * positions[..., None]
  rgb, sigma = query_field(model, params["coarse"], points, viewdirs, config, keys[1])
  sigma = jnp.where(valid, sigma, 0.0)  # unused slots: zero-width and empty
  t = occupancy.interleave_gaps(starts, ends, t_max)
  out = rendering.composite(occupancy.with_gaps(rgb, axis=-2), occupancy.with_gaps(sigma), t,
                            background)
  out["t"] = t
  return out


def render_rays(model, params, rays, config, near, far, key=None, background=None,
                viewdirs=None):
  """Render a batch of rays with the coarse and (optionally) fine passes.

  params: {'coarse': ..., ['fine': ...], ['occupancy': ...]} (see `init_params`; with
  `config.occupancy.enabled` the samples go where the grid is occupied, see occupancy.py).
  near, far: float bounds (z-depth). key: PRNG key for
  stratified jitter, resampling and density noise; None renders deterministically.
  background: None or float32 broadcastable to [..., 3]. viewdirs: float32 [..., 3] unit
  directions for the view branch (None = the normalised ray directions; pass the world
  directions when the rays are in NDC).
  Returns {'coarse': pass_output, ['fine': pass_output]}.
  """
  batch_shape = rays.origins.shape[:-1]
  keys = jax.random.split(key, 4) if key is not None else [None] * 4
  t_near, t_far = near, far
  box = config.data.get("scene_bound", 0.0)
  if box > 0:  # sample only the part of each ray inside the scene box
    t_near, t_far = grid.ray_box_bounds(rays.origins, rays.directions, box, near, far)
  viewdirs = rays.viewdirs if viewdirs is None else viewdirs
  if uses_occupancy(config):
    outputs = {"coarse": _shade_occupied(model, params, rays, viewdirs, t_near, t_far, config,
                                         background, keys[:2])}
  else:
    t = sampling.stratified(t_near, t_far, config.num_samples, batch_shape, keys[0],
                            lindisp=config.data.lindisp)
    outputs = {"coarse": _shade(model, params["coarse"], rays, viewdirs, t, config, background,
                                keys[1])}
  if config.num_fine_samples > 0:
    extra = sampling.sample_pdf(t, outputs["coarse"]["weights"], config.num_fine_samples, keys[2])
    t_fine = sampling.merge_edges(t, extra)
    fine_params = params["coarse"] if config.model.shared_fine else params["fine"]
    outputs["fine"] = _shade(model, fine_params, rays, viewdirs, t_fine, config, background,
                             keys[3])
  if box > 0:
    for out in outputs.values():
      out["depth"] = empty_depth_is_far(out, far)
  return outputs


def empty_depth_is_far(out, far):
  """float32 [...]: out['depth'] with `far` for empty rays (acc <= EMPTY_ACC).

  In a scene box composite gives an empty ray the box exit t_S; this makes it `far` on every
  code path, as without a box.
  """
  return jnp.where(out["acc"] > rendering.EMPTY_ACC, out["depth"], far)


def final(outputs):
  """The best pass of `render_rays` outputs: fine if present, else coarse."""
  return outputs.get("fine", outputs["coarse"])


def make_chunk_renderer(model, config, near, far):
  """A jitted deterministic renderer for one fixed-size chunk of rays.

  Returns fn(params, origins, directions, viewdirs, background) -> dict of rgb [C, 3],
  depth [C], acc [C].
  """
  @jax.jit
  def render_chunk(params, origins, directions, viewdirs, background):
    out = final(render_rays(model, params, Rays(origins, directions), config, near, far,
                            key=None, background=background, viewdirs=viewdirs))
    return {k: out[k] for k in ("rgb", "depth", "acc")}
  return render_chunk


def render_image(render_chunk, params, origins, directions, chunk, background=(0.0, 0.0, 0.0),
                 viewdirs=None):
  """Render any number of rays in fixed-size padded chunks (no recompiles, bounded memory).

  render_chunk: from `make_chunk_renderer`. origins, directions: float32 [..., 3]. viewdirs:
  float32 [..., 3] or None (= normalised directions). chunk: int, rays per call.
  background: RGB. Returns numpy dict rgb [..., 3], depth [...], acc [...].
  """
  batch_shape = np.shape(origins)[:-1]
  num_rays, (origins, directions, viewdirs) = _padded_rays(chunk, origins, directions, viewdirs)
  background = jnp.asarray(background, jnp.float32)
  pieces = [render_chunk(params, origins[i:i + chunk], directions[i:i + chunk],
                         viewdirs[i:i + chunk], background)
            for i in range(0, len(origins), chunk)]
  return _joined(pieces, num_rays, batch_shape)


def _padded_rays(chunk, origins, directions, viewdirs):
  """(num_rays, [origins, directions, viewdirs]): float32 [..., 3] rays flattened to [P, 3],
  P the next multiple of `chunk`; viewdirs None = normalised directions. Padding rays are copies
  of ray 0, so they are as well-behaved as a real ray."""
  if viewdirs is None:
    viewdirs = safe_normalize(jnp.asarray(directions))
  num_rays = int(np.prod(np.shape(origins)[:-1]))
  padded = -(-num_rays // chunk) * chunk
  flat = lambda a: np.asarray(a, np.float32).reshape(-1, 3)
  pad = lambda a: np.concatenate([a, np.repeat(a[:1], padded - num_rays, axis=0)])
  return num_rays, [pad(flat(a)) for a in (origins, directions, viewdirs)]


def _joined(pieces, num_rays, batch_shape):
  """Per-chunk output dicts -> one numpy dict with leading shape batch_shape (padding dropped)."""
  out = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs)[:num_rays], *pieces)
  return {k: v.reshape(*batch_shape, *v.shape[1:]) for k, v in out.items()}


def marches(config):
  """Whether rendering `config`'s model skips empty space and stops at opaque surfaces.

  `config.render.march` applies to single-pass models sampling a scene box (data.scene_bound >
  0) with plain stratified samples; any other model renders on the plain path.
  """
  return bool(config.render.get("march", False) and config.data.get("scene_bound", 0.0) > 0
              and config.num_fine_samples == 0 and not uses_occupancy(config)
              and not config.data.get("ndc", False))


def make_image_renderer(model, config, near, far):
  """fn(params) -> draw(origins, directions, viewdirs, background) -> numpy dict rgb [..., 3],
  depth [...], acc [...], rendering any number of rays in chunks of `config.render.chunk`.

  origins, directions, viewdirs: float32 [..., 3] (viewdirs None = normalised directions).
  The plain path (`make_chunk_renderer` + `render_image`) or, where `marches(config)`, the
  marching one (marching.py: the same samples, the field queried only where they matter); the
  skip grid of the marching path is computed once per call with new params.
  """
  if not marches(config):
    render_chunk = make_chunk_renderer(model, config, near, far)
    # Parameters go to the device once, not with every chunk (restored ones are numpy arrays).
    return lambda params: functools.partial(render_image, render_chunk, jax.device_put(params),
                                            chunk=config.render.chunk)
  marcher = _Marcher(model, config, near, far)
  return marcher.bind


class _Marcher:
  """The jitted pieces of marching.py for one model and config (compiled once, reused)."""

  def __init__(self, model, config, near, far):
    self.config = config
    rc, box = config.render, config.data.scene_bound

    def field(params, points, viewdirs):  # [B, 3], [B, 3] -> rgb [B, 3], sigma [B]
      rgb, sigma = query_field(model, params["coarse"], points[:, None, :], viewdirs, config)
      return rgb[:, 0], sigma[:, 0]

    self.skip_grid = jax.jit(lambda params: marching.skip_grid(
        coarse_density(model, params, config), rc.march_grid, box, rc.march_threshold))
    self.query_round = marching.make_query_round(field)

    @jax.jit
    def plan(mask, origins, directions):
      t_near, t_far = grid.ray_box_bounds(origins, directions, box, near, far)
      t = sampling.stratified(t_near, t_far, config.num_samples, origins.shape[:-1], None,
                              lindisp=config.data.lindisp)
      points = origins[:, None, :] + directions[:, None, :] * sampling.midpoints(t)[..., None]
      return (t, points, *marching.occupied_ranks(mask, points, box))

    @jax.jit
    def finish(sigma, rgb, t, background):
      out = rendering.composite(rgb, sigma, t, background)
      return {"rgb": out["rgb"], "depth": empty_depth_is_far(out, far), "acc": out["acc"]}

    self.plan, self.finish = plan, finish

  def bind(self, params):
    """The draw function of `make_image_renderer` for `params`."""
    params = jax.device_put(params)  # once, not with every query
    mask = self.skip_grid(params)
    return functools.partial(self.draw, params, mask)

  def draw(self, params, mask, origins, directions, viewdirs=None, background=(0.0, 0.0, 0.0)):
    rc, chunk = self.config.render, self.config.render.chunk
    batch_shape = np.shape(origins)[:-1]
    num_rays, (origins, directions, viewdirs) = _padded_rays(chunk, origins, directions, viewdirs)
    live = np.arange(len(origins)) < num_rays  # padding rays query nothing
    background = jnp.asarray(background, jnp.float32)
    pieces = []
    for i in range(0, len(origins), chunk):
      part = slice(i, i + chunk)
      t, points, occupied, rank = self.plan(mask, origins[part], directions[part])
      sigma, rgb, _ = marching.march(self.query_round, params, t, points, viewdirs[part],
                                     occupied, rank, live[part], rc.march_group,
                                     rc.min_transmittance)
      pieces.append(self.finish(sigma, rgb, t, background))
    return _joined(pieces, num_rays, batch_shape)
