"""Rendering rays: sample -> query the field -> composite, with an optional fine pass.

rays: `rays.Rays` (origins, directions, viewdirs, near, far) with batch shape `...`.
A pass's output (a dict): rgb float32 [..., 3], depth float32 [...], acc float32 [...],
weights float32 [..., S], t float32 [..., S + 1].
The field's density is per unit of world length; t is z-depth along un-normalised directions,
so every pass composites `per_unit_t(sigma, rays)` = σ·|d| (as the original NeRF, jaxnerf and
multinerf scale their intervals by |d|), and depth stays z-depth.
Rendering whole images in fixed-size chunks is image_renderer.py.
"""

import jax
import jax.numpy as jnp

from nerf_jax import compositing, field, occupancy, sampling
from nerf_jax.rays import ray_box_bounds


def _shade(model, params, rays, t, config, background, key):
  """One pass over the intervals `t: float32 [..., S + 1]`."""
  positions = sampling.midpoints(t)
  points = rays.origins[..., None, :] + rays.directions[..., None, :] * positions[..., None]
  rgb, sigma = field.query_in_chunks(model, params, points, rays.viewdirs, config, key,
                                     config.train.remat_chunk)
  out = compositing.composite(rgb, per_unit_t(sigma, rays), t, background)
  out["t"] = t
  return out


def per_unit_t(sigma, rays):
  """Density per unit of t: sigma float32 [..., S] (per unit of world length) times |d| of
  `rays` [...]. A ray's t advances |d| world units per unit, so its optical depth over [t_i,
  t_{i+1}] is σ·|d|·(t_{i+1} - t_i)."""
  return sigma * jnp.linalg.norm(rays.directions, axis=-1)[..., None]


def _shade_occupied(model, params, rays, t_min, t_max, config, background, keys):
  """One pass over the occupied intervals of [t_min, t_max] (float32 [...]); see occupancy.py."""
  oc = config.occupancy
  mask = occupancy.occupied_mask(jax.lax.stop_gradient(params["occupancy"]), oc.threshold)
  starts, ends, valid = occupancy.sample_occupied(
      mask, rays.origins, rays.directions, t_min, t_max, config.data.scene_bound, oc.candidates,
      config.num_samples)
  u = 0.5 if keys[0] is None else jax.random.uniform(keys[0], starts.shape, jnp.float32)
  positions = starts + (ends - starts) * u
  points = rays.origins[..., None, :] + rays.directions[..., None, :] * positions[..., None]
  rgb, sigma = field.query(model, params["coarse"], points, rays.viewdirs, config, keys[1])
  sigma = jnp.where(valid, per_unit_t(sigma, rays), 0.0)  # unused slots: zero-width and empty
  t = occupancy.interleave_gaps(starts, ends, t_max)
  out = compositing.composite(occupancy.with_gaps(rgb, axis=-2), occupancy.with_gaps(sigma), t,
                              background)
  out["t"] = t
  return out


def sample_bounds(rays, config):
  """(t_near, t_far) float32 [...]: the rays' [near, far], cut to the scene box if there is one."""
  box = config.data.scene_bound
  if box > 0:  # sample only the part of each ray inside the scene box
    return ray_box_bounds(rays.origins, rays.directions, box, rays.near, rays.far)
  return rays.near, rays.far


def render_rays(model, params, rays, config, key=None, background=None):
  """Render a batch of rays with the coarse and (optionally) fine passes.

  params: {'coarse': ..., ['fine': ...], ['occupancy': ...]} (see `field.init_params`; with
  `config.occupancy.enabled` the samples go where the grid is occupied, see occupancy.py).
  rays: Rays [...]. key: PRNG key for stratified jitter, resampling and density noise; None
  renders deterministically. background: None or float32 broadcastable to [..., 3].
  Returns {'coarse': pass_output, ['fine': pass_output]}.
  """
  keys = jax.random.split(key, 4) if key is not None else [None] * 4
  t_near, t_far = sample_bounds(rays, config)
  if occupancy.enabled(config):
    outputs = {"coarse": _shade_occupied(model, params, rays, t_near, t_far, config, background,
                                         keys[:2])}
  else:
    t = sampling.stratified(t_near, t_far, config.num_samples, rays.shape, keys[0],
                            lindisp=config.data.lindisp)
    outputs = {"coarse": _shade(model, params["coarse"], rays, t, config, background, keys[1])}
  if config.num_fine_samples > 0:
    extra = sampling.sample_pdf(t, outputs["coarse"]["weights"], config.num_fine_samples, keys[2])
    t_fine = sampling.merge_edges(t, extra)
    fine_params = params["coarse"] if config.model.shared_fine else params["fine"]
    outputs["fine"] = _shade(model, fine_params, rays, t_fine, config, background, keys[3])
  if config.data.scene_bound > 0:
    for out in outputs.values():
      out["depth"] = empty_depth_is_far(out, rays.far)
  return outputs


def empty_depth_is_far(out, far):
  """float32 [...]: out['depth'] with `far` (float32 [...]) for empty rays (acc <= EMPTY_ACC).

  In a scene box composite gives an empty ray the box exit t_S; this makes it `far` on every
  code path, as without a box.
  """
  return jnp.where(out["acc"] > compositing.EMPTY_ACC, out["depth"], far)


def final(outputs):
  """The best pass of `render_rays` outputs: fine if present, else coarse."""
  return outputs.get("fine", outputs["coarse"])


def occupancy_grid(model, params, config, key=None):
  """The occupancy grid of the coarse network's density: float32 [R, R, R] (see occupancy.py),
  probed at config.occupancy.probes per cell side, jittered from `key` (None: not jittered)."""
  oc = config.occupancy
  return occupancy.density_grid(field.coarse_density(model, params, config), oc.resolution,
                                config.data.scene_bound, oc.probes, key)
