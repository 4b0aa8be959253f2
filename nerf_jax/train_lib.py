"""Training: optimizer, the jitted train step, and `train_and_evaluate`.

Training data live on the device as flat per-pixel arrays (see `TrainData`); every step draws its
own batch inside the jitted step from a key folded with the step number, so there is no host
work or host-device transfer per step and a resumed run draws exactly the batches it would have.
With several devices each batch is split over them (see parallel.py); the parameters are
replicated. With several processes only process 0 reads and writes the workdir.
"""

import collections
import functools
import io
import json
import os
import signal
import sys
import time

import flax.struct
import jax
import jax.numpy as jnp
import ml_collections
import numpy as np
import optax

from nerf_jax import (background, budget, checkpoints, config_lib, experiment, lpips, metrics,
                      occupancy, outputs, parallel, progress, regularizers, renderer, summary)
from nerf_jax.experiment import TrainingError, TrainState  # noqa: F401  (re-exported)
from nerf_jax.rays import Rays, pixel_rays
from nerf_jax.viewer import training as live_viewer


@flax.struct.dataclass
class TrainData:
  """Training pixels, one row per image (P = H·W pixels each).

  rays: Rays [N, P], every pixel's ray; or None: each step makes the rays of the pixels it
    draws from `poses` and `camera` (what make_train_data does: 44 bytes per pixel less, which
    at 800 x 800 x 80 views is 2.3 GB).
  rgb: float32 [N, P, 3], target colours composited on the configured background.
  acc: float32 [N, P], ground-truth opacity (ones where unknown), for random backgrounds.
  poses: float32 [N, 4, 4], camera-to-world of each image (with rays None).
  camera: static (height, width, intrinsics, near, far, pixel_center, use_ndc): the arguments
    of `rays.pixel_rays` that every image shares (with rays None).
  """
  rays: Rays
  rgb: jnp.ndarray
  acc: jnp.ndarray
  poses: jnp.ndarray = None
  camera: tuple = flax.struct.field(pytree_node=False, default=None)


def make_train_data(exp):
  """TrainData of every pixel of the training images, targets on `config.data.background`;
  rays are made per step from the poses (Experiment.rays' camera and conventions)."""
  ds = exp.train_ds
  height, width, intrinsics = exp.camera()
  camera = (height, width, tuple(float(v) for v in intrinsics), float(exp.near), float(exp.far),
            float(exp.pixel_center), bool(exp.config.data.ndc))
  acc, rgb = _targets(exp)
  return TrainData(rays=None, rgb=jnp.asarray(rgb, jnp.float32).reshape(len(ds), -1, 3),
                   acc=jnp.asarray(acc, jnp.float32).reshape(len(ds), -1),
                   poses=jnp.asarray(ds.poses, jnp.float32), camera=camera)


def _pixel_rays(data, image, pixel):
  """Rays [B] of pixels `pixel` (int32 [B], row-major index in its image) of images `image`
  (int32 [B]), made from data.poses and data.camera."""
  height, width, intrinsics, near, far, pixel_center, use_ndc = data.camera
  i = (pixel % width).astype(jnp.float32)
  j = (pixel // width).astype(jnp.float32)
  one = lambda i, j, c2w: pixel_rays(i, j, height, width, intrinsics, c2w, near, far,
                                     pixel_center, use_ndc)
  return jax.vmap(one)(i, j, data.poses[image])


def _targets(exp):
  """(acc [N, H, W], rgb [N, H, W, 3]): targets on the configured background (see
  outputs.images_on_background)."""
  return outputs.images_on_background(exp.train_ds, exp.config)


def draw_batch(data, config, key, step=0, run_key=None):
  """One step's pixels: a TrainData whose fields are flattened to [B, ...].

  key: this step's PRNG key. step: int32 [], the step number. run_key: the run's PRNG key, used
  by train.image_order='epochs' (whole-image batching), where every epoch visits each training
  image once in an order drawn from the epoch number, dropping the remainder (as the
  Keras reference's batch(drop_remainder=True) epochs do).
  """
  num_images, num_pixels = data.rgb.shape[:2]
  if config.train.batching == "images":
    per_step = config.train.images_per_step
    if config.train.image_order == "epochs":
      run_key = key if run_key is None else run_key
      steps_per_epoch = max(num_images // per_step, 1)
      # A stream of its own: fold_in(run_key, n) is already step n's key.
      epochs_key = jax.random.split(run_key)[1]
      order = jax.random.permutation(jax.random.fold_in(epochs_key, step // steps_per_epoch),
                                     num_images)
      images = jax.lax.dynamic_slice(order, ((step % steps_per_epoch) * per_step,), (per_step,))
    else:
      images = jax.random.choice(key, num_images, (per_step,), replace=False)
    take = lambda a: a[images].reshape(-1, *a.shape[2:])
    image = jnp.repeat(images, num_pixels)
    pixel = jnp.tile(jnp.arange(num_pixels), per_step)
  else:
    idx = jax.random.randint(key, (config.train.batch_rays,), 0, num_images * num_pixels)
    take = lambda a: a.reshape(-1, *a.shape[2:])[idx]
    image, pixel = idx // num_pixels, idx % num_pixels
  rays = (jax.tree_util.tree_map(take, data.rays) if data.rays is not None else
          _pixel_rays(data, image, pixel))
  return TrainData(rays=rays, rgb=take(data.rgb), acc=take(data.acc))


def make_train_step(exp, mesh=None):
  """The jitted train step: (state, data, key[, planned_steps]) -> (state, stats). `state` is
  donated. planned_steps: int32 [], the length of a time budget's fitted schedule (see
  experiment.make_schedule; one compiled step for any length), or absent for the config's.

  mesh: a `parallel.make_mesh` Mesh to split each batch over its devices (data and state
  replicated on it), or None for one device.
  """
  ray_renderer, tx, config = exp.renderer, exp.tx, exp.config
  oc = ray_renderer.sampler.occupancy
  fixed_background = jnp.asarray(background.parse(config.data.background))
  random_background = background.trains_on_random(config.train.random_background,
                                                  exp.train_ds.accs is not None)

  def loss_fn(params, buffers, batch, key):
    render_key, bg_key = jax.random.split(key)
    bg, target = fixed_background, batch.rgb
    if random_background:
      # A fresh background per ray: the field cannot bake the background into density.
      bg = jax.random.uniform(bg_key, batch.rgb.shape)
      target = background.recomposite(batch.rgb, batch.acc, fixed_background, bg)
    outs = ray_renderer.render({"params": params, **buffers}, batch.rays, render_key, bg,
                               config.train.remat_chunk)
    mses = {name: jnp.mean((out["rgb"] - target) ** 2) for name, out in outs.items()}
    loss = mses["coarse"] if "fine" not in mses else (
        mses["fine"] + config.train.coarse_loss_weight * mses["coarse"])
    best = mses.get("fine", mses["coarse"])
    if config.train.distortion_weight > 0:  # keep each ray's weight in one place: no floaters
      last = renderer.final(outs)
      loss = loss + config.train.distortion_weight * jnp.mean(
          regularizers.distortion(last["t"], last["weights"]))
    return loss, {"loss": loss, "psnr": metrics.mse_to_psnr(best)}

  def refresh_occupancy(state, run_key):
    """Every `update_every` steps, probe the density field at jittered positions (drawn from the
    step: a resumed run probes where the uninterrupted one did) and accumulate them into the
    occupancy grid with decay (occupancy.accumulate). Returns the buffers."""
    if oc is None:
      return state.buffers
    # A stream of its own: fold_in(run_key, n) is step n's key, and step 2^32 - 1 never comes.
    key = jax.random.fold_in(jax.random.fold_in(run_key, 0xFFFFFFFF), state.step)
    refresh = lambda s: occupancy.accumulate(
        s.buffers["occupancy"], ray_renderer.occupancy_grid(s.variables, key), oc.decay)
    grid = jax.lax.cond(state.step % oc.update_every == 0, refresh,
                        lambda s: s.buffers["occupancy"], state)
    return {**state.buffers, "occupancy": grid}

  def step(state, data, run_key, planned_steps=None):
    key = jax.random.fold_in(run_key, state.step)
    batch_key, render_key = jax.random.split(key)
    batch = parallel.shard_batch(draw_batch(data, config, batch_key, state.step, run_key), mesh)
    buffers = refresh_occupancy(state, run_key)
    grads, stats = jax.grad(loss_fn, has_aux=True)(state.params, buffers, batch, render_key)
    finite = jnp.isfinite(stats["loss"]) & jnp.all(jnp.array(
        [jnp.all(jnp.isfinite(g)) for g in jax.tree_util.tree_leaves(grads)]))
    step_tx = tx if planned_steps is None else experiment.make_optimizer(config.train,
                                                                         planned_steps)
    updates, opt_state = step_tx.update(grads, state.opt_state, state.params)
    params = optax.apply_updates(state.params, updates)
    # A non-finite step is not applied (the state stays the last good one) and is reported.
    keep = lambda new, old: jax.tree_util.tree_map(lambda n, o: jnp.where(finite, n, o), new, old)
    bad_step = jnp.where((state.bad_step < 0) & ~finite, state.step, state.bad_step)
    new_state = TrainState(step=state.step + 1, params=keep(params, state.params),
                           opt_state=keep(opt_state, state.opt_state), bad_step=bad_step,
                           buffers=keep(buffers, state.buffers))
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


class _StopRequest:
  """Turns SIGINT/SIGTERM into a flag the loop checks, so the run saves before it exits."""

  def __init__(self):
    self.signum = None

  def __enter__(self):
    self._old = {s: signal.signal(s, self._handle) for s in (signal.SIGINT, signal.SIGTERM)}
    return self

  def _handle(self, signum, frame):
    self.signum = signum

  def __exit__(self, *exc):
    for s, handler in self._old.items():
      signal.signal(s, handler)


def _log(workdir, record):
  with open(os.path.join(workdir, "metrics.jsonl"), "a") as f:
    f.write(json.dumps(record) + "\n")


def rays_per_step(config, dataset):
  """Rays in one train step: a batch of random rays, or whole images."""
  tc = config.train
  if tc.batching == "images":
    return tc.images_per_step * dataset.height * dataset.width
  return tc.batch_rays


def train_and_evaluate(config, workdir):
  """Train on `config.data`, checkpoint into `workdir`, evaluate the test views at the end.

  Resumes from the newest checkpoint in `workdir`. Returns the final metrics dict (also written to
  `workdir/metrics.json`). Writes metrics.jsonl and TensorBoard events (workdir/tb) at log steps.
  The run lasts train.max_steps steps if set, else until train.max_seconds with the schedule
  fitted to the steps expected in it (budget.py), else train.default_steps steps; the run's
  config.json holds the schedule it used.
  """
  main = parallel.is_main_process()
  config = config_lib.upgrade(config)
  parallel.check_time_budget(config.train)
  if main:
    os.makedirs(workdir, exist_ok=True)
  exp = experiment.setup(config)
  near, far = exp.near, exp.far
  signature = experiment.model_signature(config)
  state, meta = _start_state(exp, workdir, signature)
  elapsed = float(meta.get("wall_seconds", 0.0))
  t_start = time.perf_counter() - elapsed  # a time budget's calibration counts against it

  mesh = parallel.make_mesh(config.train.data_parallel)
  step_rays = rays_per_step(config, exp.train_ds)
  parallel.check_batch(step_rays, mesh)
  data = parallel.replicate(make_train_data(exp), mesh)
  key = jax.random.PRNGKey(config.seed + 1)
  train_step = cached_train_step(exp, mesh)
  last_step = budget.planned_steps(config.train)
  if budget.fits_time(config.train):
    config = _fit_to_time(exp, train_step, data, key, mesh, meta, t_start)
    planned = jnp.int32(config.train.max_steps)
    train_step = functools.partial(train_step, planned_steps=planned)
    last_step = sys.maxsize  # the clock ends the run
  if main:  # with the schedule the run uses
    checkpoints.atomic_write(os.path.join(workdir, "config.json"),
                             config.to_json(indent=2).encode())
  tc = config.train
  state = parallel.replicate(state, mesh)
  evaluate = outputs.make_evaluator(exp)
  schedule = experiment.make_schedule(tc)
  writer = summary.Writer(workdir, enabled=main and tc.tensorboard)
  start_step = int(state.step)
  last_log, last_log_step = time.perf_counter(), start_step
  step = start_step
  planned = budget.planned_steps(tc)
  bar = progress.Progress(planned, "train", start=start_step,
                          stream=None if main else io.StringIO())
  viewer = live_viewer.start(exp, workdir, enabled=main)
  with _StopRequest() as stop:
    while step < last_step:
      state, stats = train_step(state, data, key)
      step += 1
      viewer.after_step(step, lambda: _one_device(state.variables, mesh))
      budget_over = tc.max_seconds > 0 and time.perf_counter() - t_start >= tc.max_seconds
      log_now = step % tc.log_every == 0 or step == last_step or budget_over or stop.signum
      if log_now:
        stats = jax.device_get(stats)
        _check_finite(state, workdir)
        now = time.perf_counter()
        rays_s = (step - last_log_step) * step_rays / max(now - last_log, 1e-9)
        last_log, last_log_step = now, step
        wall = now - t_start
        record = {"step": step, "wall_seconds": round(wall, 3), "loss": float(stats["loss"]),
                  "train_psnr": float(stats["psnr"]), "rays_per_second": round(rays_s)}
        if tc.eval_every and step % tc.eval_every == 0:
          images = {}
          record["eval_psnr"] = float(evaluate(
              _one_device(state.variables, mesh), max_views=tc.eval_views,
              on_view=_first_view_into(images, near, far))["psnr"])
          writer.images(step, images)
        if main:
          _log(workdir, record)
        writer.scalars(step, {"train/loss": record["loss"], "train/psnr": record["train_psnr"],
                              "train/learning_rate": float(schedule(step - 1)),
                              "train/rays_per_second": rays_s,
                              **({"eval/psnr": record["eval_psnr"]}
                                 if "eval_psnr" in record else {})})
        eta = max(planned - step, 0) * wall / max(step - start_step, 1)
        if tc.max_seconds > 0:
          eta = max(min(eta, tc.max_seconds - wall), 0.0)
        bar.update(step, info=f"loss {record['loss']:.5f} psnr {record['train_psnr']:.2f}")
        bar.write(f"step {step}/{planned} loss {record['loss']:.5f} "
                  f"psnr {record['train_psnr']:.2f} {rays_s:,.0f} rays/s "
                  f"elapsed {progress.format_seconds(wall)} eta {progress.format_seconds(eta)}")
      elif bar.due():
        jax.block_until_ready(state.step)  # show steps done, not steps queued (a scalar sync)
        bar.update(step)
      if step % tc.checkpoint_every == 0 or step == last_step or budget_over or stop.signum:
        _check_finite(state, workdir)  # never checkpoint a state that has seen a bad step
        _save(workdir, state, signature, tc, time.perf_counter() - t_start)
      if stop.signum:
        bar.close()
        raise KeyboardInterrupt(f"stopped by signal {stop.signum} at step {step}; "
                                f"checkpoint saved in {checkpoints.checkpoint_dir(workdir)}")
      if budget_over:
        break
  bar.close()
  viewer.close()
  train_seconds = time.perf_counter() - t_start
  _check_finite(state, workdir)
  variables = _one_device(state.variables, mesh)
  images = {}
  result = evaluate(variables, out_dir=os.path.join(workdir, "eval")
                    if config.render.after_training and main else None,
                    on_view=_first_view_into(images, near, far))
  writer.images(step, images)
  writer.scalars(step, {"test/psnr": result["psnr"], "test/ssim": result["ssim"]})
  writer.close()
  result.update(train_seconds=round(train_seconds, 3), steps=step)
  if not main:
    return result
  checkpoints.atomic_write(os.path.join(workdir, "metrics.json"),
                           json.dumps(result, indent=2).encode())
  _log(workdir, {"step": step, "wall_seconds": round(train_seconds, 3),
                 "eval_psnr": result["psnr"], "eval_ssim": result["ssim"],
                 **({"eval_lpips": result["lpips"]} if "lpips" in result else {}), "final": True})
  print(f"test PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.4f}, {lpips.describe(result)} "
        f"over {len(result['per_view'])} views after {step} steps ({train_seconds:.0f} s)",
        flush=True)
  if config.render.after_training:
    outputs.render_video(exp, variables, os.path.join(workdir, "video"))
  return result


def _start_state(exp, workdir, signature):
  """(TrainState, checkpoint meta): the newest checkpoint's in `workdir`, else a fresh state and
  {}. Only process 0 reads the workdir; the others take its state (so they agree whether or not
  they see its files) and get meta {}, which only process 0 uses."""
  ckpt = checkpoints.latest_path(workdir) if parallel.is_main_process() else None
  if not ckpt:
    state, meta = experiment.init_state(exp), {}
  else:
    state, meta = checkpoints.restore_with_meta(ckpt, experiment.state_template(exp), signature,
                                                experiment.upgrade_state_dict)
    print(f"resuming from {ckpt} at step {int(state.step)}", flush=True)
  return parallel.from_main(state), meta


def _fit_to_time(exp, train_step, data, key, mesh, meta, t_start):
  """A copy of exp.config whose step budget and schedule fit train.max_seconds (budget.py).

  A resumed run takes the schedule its checkpoint `meta` recorded (the one it started with);
  a new one first times `train_step` (which the run then uses, compiled once) on a throwaway
  fresh state, with the clock started at `t_start`.
  """
  config = ml_collections.ConfigDict(exp.config.to_dict())
  tc = config.train
  if "schedule_steps" in meta:
    tc.max_steps, tc.warmup_steps = int(meta["schedule_steps"]), int(meta["warmup_steps"])
    return config
  state = parallel.replicate(experiment.init_state(exp), mesh)
  seconds = min(budget.CALIBRATION_SECONDS, budget.CALIBRATION_SHARE * tc.max_seconds)
  step_seconds, _ = budget.calibrate(
      lambda s: train_step(s, data, key, planned_steps=jnp.int32(1))[0], state, seconds)
  left = tc.max_seconds - (time.perf_counter() - t_start)
  budget.fit_schedule(tc, budget.steps_in(left, step_seconds, 0.0))  # compiled already
  return config


def _one_device(params, mesh):
  """Parameters for rendering on one device (a replicated copy would render on every device)."""
  if mesh is None:
    return params
  return jax.device_put(parallel.to_host(params), jax.local_devices()[0])


def _first_view_into(images, near, far):
  """An evaluator `on_view` callback putting the first view's TensorBoard images in `images`."""
  def on_view(index, out, truth):
    if index == 0:
      images.update({"eval/rgb": outputs.to_uint8(out["rgb"]),
                     "eval/depth": outputs.colorize(out["depth"], near, far),
                     "eval/truth": outputs.to_uint8(truth)})
  return on_view


def _save(workdir, state, signature, train_config, elapsed):
  """Checkpoint `state` (process 0 only); its meta holds the wall seconds spent so far and the
  schedule (a time-budget run resumes on the schedule it fitted)."""
  host_state = parallel.to_host(state)
  if parallel.is_main_process():
    checkpoints.save(workdir, int(host_state.step), host_state, signature,
                     train_config.keep_checkpoints,
                     meta={"wall_seconds": elapsed,
                           "schedule_steps": budget.planned_steps(train_config),
                           "warmup_steps": int(train_config.warmup_steps)})


def _check_finite(state, workdir):
  bad = int(state.bad_step)
  if bad >= 0:
    last = checkpoints.latest_path(workdir) or "none yet"
    raise TrainingError(f"non-finite loss or gradient at step {bad + 1}; the update was not "
                        f"applied; last good checkpoint: {last}. Try a lower config.train.lr "
                        "or set config.train.grad_clip.")
