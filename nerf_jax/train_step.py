"""The jitted train step: draw a batch, refresh the occupancy grid, render, take a gradient
step of Adam; a non-finite step is not applied and is reported.

With appearance codes each ray is rendered with its training image's code; with pose refinement
each ray is made from its camera's corrected pose (pose_refinement.py), so the corrections
params['poses'] take a gradient, and the positional encoding's bands open coarse to fine.

With several devices each batch is split over them (see parallel.py); the parameters are
replicated.
"""

import collections
import math

import jax
import jax.numpy as jnp
import optax

from nerf_jax import (background, experiment, metrics, model, occupancy, parallel,
                      pose_refinement, regularizers, renderer, train_batches)
from nerf_jax.experiment import TrainState


def _render_split(render, rays, key, background, image, posed):
  """`render(rays, key, background, image)` of a batch of rays [B] in two parts: the first
  `posed` rays as they are, the rest from stop_gradient(rays), so the backward pass computes
  no gradient with respect to their samples' positions (with pose refinement that gradient,
  through every sample's interpolation, is most of the extra cost of a step). background:
  float32 [3] or [B, 3]; image: int32 [B] or None. Returns the two parts' outputs joined along
  the rays, in the rays' order."""
  parts = (slice(None, posed), slice(posed, None))
  keys = jax.random.split(key)
  outs = []
  for part, part_key, stop in zip(parts, keys, (False, True)):
    part_rays = jax.tree_util.tree_map(lambda a: a[part], rays)
    if stop:
      part_rays = jax.lax.stop_gradient(part_rays)
    part_bg = background[part] if jnp.ndim(background) == 2 else background
    outs.append(render(part_rays, part_key, part_bg, None if image is None else image[part]))
  return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), *outs)


def _mse(rgb, target, complete=None):
  """Mean squared error of rgb float32 [B, 3] against target float32 [B, 3], over the rays
  with complete bool [B] (None: all rays). A sample budget always completes its first ray
  unless that ray alone has more valid samples than the budget: max(count, 1) keeps it finite."""
  if complete is None:
    return jnp.mean((rgb - target) ** 2)
  squared = jnp.where(complete[:, None], (rgb - target) ** 2, 0.0)
  return jnp.sum(squared) / (3.0 * jnp.maximum(jnp.sum(complete), 1))


def make_train_step(exp, mesh=None):
  """The jitted train step: (state, data, key[, planned_steps]) -> (state, stats). `state` is
  donated. planned_steps: int32 [], the length of a time budget's fitted schedule (see
  experiment.make_schedule; one compiled step for any length), or absent for the config's.

  mesh: a `parallel.make_mesh` Mesh to split each batch over its devices (data and state
  replicated on it), or None for one device.
  """
  ray_renderer, tx, config = experiment.training_renderer(exp), exp.tx, exp.config
  oc = ray_renderer.sampler.occupancy
  fixed_background = jnp.asarray(background.parse(config.data.background))
  random_background = background.trains_on_random(config.train.random_background,
                                                  exp.train_ds.accs is not None)
  refine = config.train.pose_refinement
  image_of = lambda batch: batch.image if ray_renderer.field.uses_images else None

  def bands_at(step, planned_steps):
    """BARF's α: positional-encoding bands (or grid levels) open between the shares
    train.pose_coarse_to_fine of the planned steps (None without pose refinement: all open)."""
    dims = ray_renderer.field.coarse_to_fine_stages
    if not refine or not dims:
      return None
    start, end = config.train.pose_coarse_to_fine
    planned = experiment.schedule_steps(config.train) if planned_steps is None else planned_steps
    share = step.astype(jnp.float32) / jnp.maximum(planned, 1)
    return dims * jnp.clip((share - start) / max(end - start, 1e-6), 0.0, 1.0)

  def posed_rays(num_rays):
    """How many of a batch's rays carry the poses' gradient: ceil(train.pose_ray_share ·
    num_rays), or None for all of them (or without refinement): a share that rounds up to the
    whole batch renders it in one part, not with an empty second part."""
    share = config.train.pose_ray_share
    posed = max(1, math.ceil(share * num_rays))
    if not refine or posed >= num_rays:
      return None
    return posed

  def loss_fn(params, buffers, batch, key, data=None, bands=None):
    render_key, bg_key = jax.random.split(key)
    bg, target = fixed_background, batch.rgb
    if random_background:
      # A fresh background per ray: the field cannot bake the background into density.
      bg = jax.random.uniform(bg_key, batch.rgb.shape)
      target = background.recomposite(batch.rgb, batch.acc, fixed_background, bg)
    rays = batch.rays
    if refine:  # the rays of the corrected cameras: the corrections take a gradient
      rays = train_batches.pixel_rays_of(
          data, batch.image, batch.pixel, pose_refinement.corrected(data.poses, params["poses"]))
    render = lambda rays, key, bg, image: ray_renderer.render(
        {"params": params, **buffers}, rays, key, bg, config.train.remat_chunk, image, bands)
    posed = posed_rays(rays.near.shape[0])
    if posed is None:
      outs = render(rays, render_key, bg, image_of(batch))
    else:  # only the first `posed` rays' gradient reaches the poses
      outs = _render_split(render, rays, render_key, bg, image_of(batch), posed)
    complete = outs["coarse"].get("complete")  # a sample budget: only whole rays count
    mses = {name: _mse(out["rgb"], target, complete) for name, out in outs.items()}
    loss = mses["coarse"] if "fine" not in mses else (
        mses["fine"] + config.train.coarse_loss_weight * mses["coarse"])
    best = mses.get("fine", mses["coarse"])
    if config.train.distortion_weight > 0:  # keep each ray's weight in one place: no floaters
      # In normalised ray distance (mip-NeRF 360's s): the same weight at any scene scale, and
      # finite for an unbounded scene's edges out to 1e10. It shapes the weights only: no
      # gradient reaches the cameras (pose refinement) through the edges.
      last = renderer.final(outs)
      s = jax.lax.stop_gradient(ray_renderer.sampler.unit_distance(last["t"], rays))
      loss = loss + config.train.distortion_weight * jnp.mean(
          regularizers.distortion(s, last["weights"]))
    if refine and config.train.pose_prior > 0:
      # A zero-mean Gaussian prior on each camera's correction (rotation in radians, move in
      # scene units): directions the images barely constrain stay near the given poses
      # instead of drifting with the field's noise.
      loss = loss + config.train.pose_prior * jnp.mean(jnp.sum(params["poses"] ** 2, axis=-1))
    if config.train.tv_weight > 0:  # smooth tables where few rays constrain them (LLFF)
      tables = model.lattice_tables(params)
      loss = loss + config.train.tv_weight * sum(
          regularizers.total_variation(table, axes) for table, axes in tables)
    stats = {"loss": loss, "psnr": metrics.mse_to_psnr(best)}
    if complete is not None:  # how many rays the budget held whole
      stats["rays_in_loss"] = jnp.sum(complete, dtype=jnp.int32)
    return loss, stats

  def refresh_occupancy(state, run_key):
    """Every `update_every` steps, probe the density field at jittered positions (drawn from the
    step: a resumed run probes where the uninterrupted one did) and accumulate them into the
    occupancy grid with decay (occupancy.accumulate). Returns the buffers."""
    if oc is None:
      return state.buffers
    # A stream of its own: fold_in(run_key, n) is step n's key, and step 2^32 - 1 never comes.
    key = jax.random.fold_in(jax.random.fold_in(run_key, 0xFFFFFFFF), state.step)
    refresh = lambda s: occupancy.accumulate(
        s.buffers["occupancy"], ray_renderer.occupancy_grid(s.variables, key), oc.decay
    ) * s.buffers.get("hull", 1.0)  # what the masks rule out stays empty
    grid = jax.lax.cond(state.step % oc.update_every == 0, refresh,
                        lambda s: s.buffers["occupancy"], state)
    return {**state.buffers, "occupancy": grid}

  def step(state, data, run_key, planned_steps=None):
    key = jax.random.fold_in(run_key, state.step)
    batch_key, render_key = jax.random.split(key)
    batch = parallel.shard_batch(
        train_batches.draw_batch(data, config, batch_key, state.step, run_key), mesh)
    buffers = refresh_occupancy(state, run_key)
    grads, stats = jax.grad(loss_fn, has_aux=True)(state.params, buffers, batch, render_key,
                                                   data, bands_at(state.step, planned_steps))
    finite = jnp.isfinite(stats["loss"]) & jnp.all(jnp.array(
        [jnp.all(jnp.isfinite(g)) for g in jax.tree_util.tree_leaves(grads)]))
    step_tx = tx if planned_steps is None else experiment.optimizer_for(config, planned_steps)

    def apply(params_and_state):
      params, opt_state = params_and_state
      updates, opt_state = step_tx.update(grads, opt_state, params)
      return optax.apply_updates(params, updates), opt_state
    # A non-finite step is not applied (the state stays the last good one) and is reported.
    # A cond, not a select of new and old: the select kept both copies of the parameters and
    # Adam's moments and cost 3-4x the update itself (45 ms of a 245 ms detail.py step).
    params, opt_state = jax.lax.cond(finite, apply, lambda same: same,
                                     (state.params, state.opt_state))
    buffers = jax.tree_util.tree_map(lambda n, o: jnp.where(finite, n, o), buffers, state.buffers)
    bad_step = jnp.where((state.bad_step < 0) & ~finite, state.step, state.bad_step)
    new_state = TrainState(step=state.step + 1, params=params, opt_state=opt_state,
                           bad_step=bad_step, buffers=buffers)
    return parallel.replicated_constraint(new_state, mesh), stats

  return jax.jit(step, donate_argnums=0)


_STEPS = collections.OrderedDict()  # the few most recent train steps, see `_cached_train_step`


def cached_train_step(exp, mesh=None):
  """`make_train_step`, reused for an equal config in the same process (tests, sweeps and
  resumed runs then compile it once): the step depends on nothing else."""
  key = (exp.config.to_json(), exp.near, exp.far, mesh)
  if key not in _STEPS:
    _STEPS[key] = make_train_step(exp, mesh)
    while len(_STEPS) > 4:
      _STEPS.popitem(last=False)
  _STEPS.move_to_end(key)
  return _STEPS[key]
