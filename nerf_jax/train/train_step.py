"""The jitted train step: draw a batch, update the buffers (its hooks: the occupancy grid's
refresh), render, add the loss terms, take a gradient step of the optimiser; a non-finite step
is not applied and is reported.

The step never sees a config: `make_train_step(ray_renderer, tx, terms, settings, ...)` takes
the renderer, the optimiser, the loss terms (train/losses/), `StepSettings` and the buffer
hooks, all built once by the entry layer (run/builders.train_step_args).

With appearance codes each ray is rendered with its training image's code (and with the
transient head, its image's transient embedding); with pose refinement each ray is made from its
camera's corrected pose (cameras/pose_refinement.py), so the corrections params['poses'] take a
gradient, and the positional encoding's bands open coarse to fine; with intrinsics refinement
each ray is made through its image's refined focal and the shared lens
(cameras/intrinsics_refinement.py, params['intrinsics']; the bands open coarse to fine only
with pose refinement).

With a loss term that asks for keypoint rays (losses.keypoint_rays: the depth term) each step
also draws that many keypoints (train_batches.draw_keypoints, from a key of their own folded from
the step's) and renders their rays with the same parameters, each with its image (appearance
codes), the sample budget scaled to their share of the batch; their rays come from the refined
cameras but carry no gradient to them (their depths were measured through the cameras as
loaded). Without such a term nothing of them is drawn or rendered.

With several devices each batch is split over them (see parallel.py); the parameters are
replicated.
"""

import dataclasses
import math
from typing import Tuple

import jax
import jax.numpy as jnp
import optax

from nerf_jax.backend import components, draws
from nerf_jax.cameras import pose_refinement
from nerf_jax.render import background as background_lib, renderer
from nerf_jax.samplers import occupancy
from nerf_jax.train import losses, parallel, train_batches
from nerf_jax.train.state import TrainState

# fold_in(step key, KEYPOINTS_KEY) draws and renders the step's keypoint rays: a stream of its
# own (a fold_in, not a split, so the batch's and the render's keys stay as they were).
KEYPOINTS_KEY = 0x4B59


@dataclasses.dataclass(frozen=True)
class StepSettings:
  """What a train step does besides rendering and the loss terms: config.train's fields of
  the step, and three the entry layer derives (run/builders.step_settings): batch
  (train_batches.BatchSettings, how each step's rays are drawn), background (float32 (r, g, b),
  what the targets are composited on: data.background) and planned_steps (the steps the
  learning-rate schedule spans; BARF's coarse-to-fine share is of these when the step is not
  given a fitted length). ema_decay > 0: the state keeps the weights' moving average
  (`moving_average`).
  """
  batch: train_batches.BatchSettings = components.derived()
  background: Tuple[float, float, float] = components.derived((0.0, 0.0, 0.0))
  planned_steps: int = components.derived(1)
  remat_chunk: int = 128  # rays per cache-sized, recomputed field chunk in a step (0 = off)
  random_background: bool = False  # data with opacity: composite on random colours (no floaters)
  pose_refinement: bool = False  # learn an SE(3) correction of each training camera (BARF)
  pose_coarse_to_fine: Tuple[float, float] = (0.1, 0.5)  # bands (grid levels) open between these shares of steps
  pose_ray_share: float = 1.0  # pose refinement: share of a batch's rays that move the poses
  intrinsics_refinement: bool = False  # learn a focal scale per training image, one lens (k)
  ema_decay: float = 0.0  # score and render the weights' moving average of this decay (0 = off)


def _render_split(render, rays, key, background, posed):
  """`render(rays, key, background)` of a batch of rays [B] in two parts: the first
  `posed` rays as they are, the rest from stop_gradient(rays), so the backward pass computes
  no gradient with respect to their samples' positions (with pose refinement that gradient,
  through every sample's interpolation, is most of the extra cost of a step). background:
  float32 [3] or [B, 3]. Returns the two parts' outputs joined along the rays, in the rays'
  order."""
  parts = (slice(None, posed), slice(posed, None))
  keys = jax.random.split(key)
  outs = []
  for part, part_key, stop in zip(parts, keys, (False, True)):
    part_rays = jax.tree_util.tree_map(lambda a: a[part], rays)
    if stop:
      part_rays = jax.lax.stop_gradient(part_rays)
    part_bg = background[part] if jnp.ndim(background) == 2 else background
    outs.append(render(part_rays, part_key, part_bg))
  return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), *outs)


@dataclasses.dataclass(frozen=True)
class OccupancyRefresh:
  """A buffer update: every `update_every` steps, probe the renderer's density field at jittered
  positions (drawn from the step: a resumed run probes where the uninterrupted one did) and
  accumulate them into buffers['occupancy'] with decay (occupancy.accumulate); cells that
  buffers['hull'] (the visual hull, when carved) rules out stay empty.

  ray_renderer: the training RayRenderer, whose sampler has occupancy settings."""
  ray_renderer: object

  def __call__(self, state, run_key):
    """The buffers of `state` (a TrainState) after this step's refresh."""
    oc = self.ray_renderer.sampler.occupancy
    # A stream of its own: fold_in(run_key, n) is step n's key, and step 2^32 - 1 never comes.
    key = jax.random.fold_in(jax.random.fold_in(run_key, 0xFFFFFFFF), state.step)
    refresh = lambda s: occupancy.accumulate(
        s.buffers["occupancy"], self.ray_renderer.occupancy_grid(s.training_variables, key),
        oc.decay) * self._kept(s.buffers)  # what the masks rule out stays empty
    grid = jax.lax.cond(state.step % oc.update_every == 0, refresh,
                        lambda s: s.buffers["occupancy"], state)
    return {**state.buffers, "occupancy": grid}

  def _kept(self, buffers):
    """The occupancy cells the visual hull keeps (renderer.occupancy_hull), 1 without one."""
    if "hull" not in buffers:
      return 1.0
    return renderer.occupancy_hull(self.ray_renderer.sampler, buffers["hull"],
                                   buffers["hull_bound"])


def moving_average(ema, params, decay):
  """The train state's `ema` after a step that left `params`: {'params': decay·average +
  (1 - decay)·params} (instant-ngp's Ema, decay 0.95: about the last 1/(1 - decay) = 20 steps'
  weights; with our decaying learning rate it scored 0.06 dB below the last weights on lego,
  docs/gpu.md), or {} unchanged when the run keeps none. The average starts at the initial
  weights (`init_state`), so it is unbiased without Adam's correction."""
  if not ema:
    return ema
  average = lambda a, p: decay * a + (1.0 - decay) * p
  return {"params": jax.tree_util.tree_map(average, ema["params"], params)}


def make_train_step(ray_renderer, tx, terms, settings, optimizer_for=None, mesh=None,
                    buffer_updates=()):
  """The jitted train step: (state, data, key[, planned_steps]) -> (state, stats). `state` is
  donated.

  ray_renderer: the training RayRenderer (render/renderer.py). tx: the optimiser. terms: the
  loss terms (train/losses/), added in order; stats holds 'loss' and every stat they return,
  as '<term name>/<stat>' (losses.total).
  settings: StepSettings. optimizer_for: planned_steps -> the optimiser on a schedule of that
  length, for a time budget's fitted schedule (planned_steps: int32 [], traced: one compiled
  step for any length); None when the step is always called without planned_steps.
  mesh: a `parallel.make_mesh` Mesh to split each batch over its devices (data and state
  replicated on it), or None for one device.
  buffer_updates: (state, run_key) -> buffers, each called in order at the start of a step on
  the state with the previous update's buffers (e.g. `OccupancyRefresh`); the step renders with
  the buffers they return.
  """
  fixed_background = jnp.asarray(settings.background)
  refine, lens = settings.pose_refinement, settings.intrinsics_refinement
  num_keypoints = losses.keypoint_rays(terms)

  def bands_at(step, planned_steps):
    """BARF's α: positional-encoding bands (or grid levels) open between the shares
    pose_coarse_to_fine of the planned steps (None without pose refinement: all open)."""
    dims = ray_renderer.field.coarse_to_fine_stages
    if not refine or not dims:
      return None
    start, end = settings.pose_coarse_to_fine
    planned = settings.planned_steps if planned_steps is None else planned_steps
    share = step.astype(jnp.float32) / jnp.maximum(planned, 1)
    return dims * jnp.clip((share - start) / max(end - start, 1e-6), 0.0, 1.0)

  def posed_rays(num_rays):
    """How many of a batch's rays carry the poses' gradient: ceil(pose_ray_share · num_rays),
    or None for all of them (or without refinement): a share that rounds up to the whole batch
    renders it in one part, not with an empty second part."""
    posed = max(1, math.ceil(settings.pose_ray_share * num_rays))
    if not refine or posed >= num_rays:
      return None
    return posed

  def render_keypoints(params, buffers, data, keypoints, key, bands, batch_rays):
    """The renderer's outputs of the rays of `keypoints` (train_batches.Keypoints [R]), with
    the sample budget scaled from the batch's `batch_rays` to their R."""
    poses = pose_refinement.corrected(data.poses, params["poses"]) if refine else None
    rays = jax.lax.stop_gradient(train_batches.keypoint_rays(
        data, keypoints, poses, params["intrinsics"] if lens else None))
    if ray_renderer.uses_images:
      rays = rays.replace(image=keypoints.image)
    budget = math.ceil(ray_renderer.sample_budget * len(keypoints) / batch_rays)
    return dataclasses.replace(ray_renderer, sample_budget=budget).render(
        {"params": params, **buffers}, rays, key, fixed_background, settings.remat_chunk, bands)

  def loss_fn(params, buffers, batch, key, data=None, bands=None, step=None, keypoints=None,
              keypoint_key=None):
    render_key, bg_key = jax.random.split(key)
    bg, target = fixed_background, batch.rgb
    if settings.random_background:
      # A fresh background per ray: the field cannot bake the background into density.
      bg = draws.uniform(bg_key, batch.rgb.shape)
      target = background_lib.recomposite(batch.rgb, batch.acc, fixed_background, bg)
    rays = batch.rays
    if refine or lens:  # the rays of the refined cameras: the refinements take a gradient
      poses = pose_refinement.corrected(data.poses, params["poses"]) if refine else None
      rays = train_batches.pixel_rays_of(data, batch.image, batch.pixel, poses,
                                         params["intrinsics"] if lens else None)
    if ray_renderer.uses_images:  # each ray's image: its appearance code, its transient head
      rays = rays.replace(image=batch.image)
    render = lambda rays, key, bg: ray_renderer.render(
        {"params": params, **buffers}, rays, key, bg, settings.remat_chunk, bands)
    posed = posed_rays(rays.near.shape[0])
    if posed is None:
      outs = render(rays, render_key, bg)
    else:  # only the first `posed` rays' gradient reaches the poses
      outs = _render_split(render, rays, render_key, bg, posed)
    keypoint_outs = None if keypoints is None else render_keypoints(
        params, buffers, data, keypoints, keypoint_key, bands, rays.near.shape[0])
    return losses.total(terms, losses.LossInputs(outs, target, rays, params, batch.weight,
                                                 batch.mask, step, keypoint_outs, keypoints))

  def update_buffers(state, run_key):
    for update in buffer_updates:
      state = state.replace(buffers=update(state, run_key))
    return state.buffers

  def step(state, data, run_key, planned_steps=None):
    key = jax.random.fold_in(run_key, state.step)
    batch_key, render_key = jax.random.split(key)
    batch = parallel.shard_batch(
        train_batches.draw_batch(data, settings.batch, batch_key, state.step, run_key), mesh)
    buffers = update_buffers(state, run_key)
    keypoints = keypoint_key = None
    if num_keypoints:
      draw_key, keypoint_key = jax.random.split(jax.random.fold_in(key, KEYPOINTS_KEY))
      keypoints = train_batches.draw_keypoints(data, num_keypoints, draw_key)
    grads, stats = jax.grad(loss_fn, has_aux=True)(state.params, buffers, batch, render_key,
                                                   data, bands_at(state.step, planned_steps),
                                                   state.step, keypoints, keypoint_key)
    finite = jnp.isfinite(stats["loss"]) & jnp.all(jnp.array(
        [jnp.all(jnp.isfinite(g)) for g in jax.tree_util.tree_leaves(grads)]))
    step_tx = tx if planned_steps is None else optimizer_for(planned_steps)

    def apply(trained):
      params, opt_state, ema = trained
      updates, opt_state = step_tx.update(grads, opt_state, params)
      params = optax.apply_updates(params, updates)
      return params, opt_state, moving_average(ema, params, settings.ema_decay)
    # A non-finite step is not applied (the state stays the last good one) and is reported.
    # A cond, not a select of new and old: the select kept both copies of the parameters and
    # Adam's moments and cost 3-4x the update itself (45 ms of a 245 ms detail.py step).
    params, opt_state, ema = jax.lax.cond(finite, apply, lambda same: same,
                                          (state.params, state.opt_state, state.ema))
    buffers = jax.tree_util.tree_map(lambda n, o: jnp.where(finite, n, o), buffers, state.buffers)
    bad_step = jnp.where((state.bad_step < 0) & ~finite, state.step, state.bad_step)
    new_state = TrainState(step=state.step + 1, params=params, opt_state=opt_state,
                           bad_step=bad_step, buffers=buffers, ema=ema)
    return parallel.replicated_constraint(new_state, mesh), stats

  return jax.jit(step, donate_argnums=0)
