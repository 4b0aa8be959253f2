"""Training: optimizer, the jitted train step, and `train_and_evaluate`.

Training data live on the device as flat per-pixel arrays (see `TrainData`); every step draws its
own batch inside the jitted step from a key folded with the step number, so there is no host
work or host-device transfer per step and a resumed run draws exactly the batches it would have.
With several devices each batch is split over them (see parallel.py); the parameters are
replicated and only process 0 writes files.
"""

import collections
import io
import json
import os
import signal
import time

import flax.struct
import jax
import jax.numpy as jnp
import ml_collections
import numpy as np
import optax

from nerf_jax import checkpoints, metrics, parallel, progress, render_lib, renderer, summary
from nerf_jax.data import loaders
from nerf_jax.model import make_model
from nerf_jax.rays import Rays
from nerf_jax.viewer import training as live_viewer


class TrainingError(RuntimeError):
  """Training cannot go on (non-finite loss, bad config); the message says why and what to do."""


@flax.struct.dataclass
class TrainState:
  step: jnp.ndarray  # int32 [], steps taken
  params: dict  # {'coarse': ..., ['fine': ...]}
  opt_state: optax.OptState
  bad_step: jnp.ndarray  # int32 [], first step whose loss or gradient was non-finite, -1 if none


@flax.struct.dataclass
class TrainData:
  """Training pixels, one row per image (P = H·W pixels each).

  origins, directions, viewdirs: float32 [N, P, 3], the rays (see renderer.camera_rays).
  rgb: float32 [N, P, 3], target colours composited on the configured background.
  acc: float32 [N, P], ground-truth opacity (ones where unknown), for random backgrounds.
  """
  origins: jnp.ndarray
  directions: jnp.ndarray
  viewdirs: jnp.ndarray
  rgb: jnp.ndarray
  acc: jnp.ndarray


def make_train_data(dataset, config):
  """TrainData of every pixel of a `Dataset`, targets on `config.data.background`."""
  rays = [renderer.camera_rays(dataset.height, dataset.width, dataset.intrinsics, pose, config)
          for pose in dataset.poses]
  flat = lambda a: jnp.asarray(np.asarray(a), jnp.float32).reshape(len(dataset), -1, 3)
  stack = lambda i: flat(np.stack([np.asarray(r[i]) for r in rays]))
  acc, rgb = _targets(dataset, config)
  return TrainData(origins=stack(0), directions=stack(1), viewdirs=stack(2), rgb=flat(rgb),
                   acc=jnp.asarray(acc, jnp.float32).reshape(len(dataset), -1))


def _targets(dataset, config):
  """(acc [N, H, W], rgb [N, H, W, 3]): targets on the configured background (see
  render_lib.images_on_background); 'random' is refused without per-pixel opacity."""
  wanted = config.data.background
  if getattr(dataset, "accs", None) is None and isinstance(wanted, str) and wanted == "random":
    raise TrainingError("config.data.background='random' needs per-pixel opacity (Blender "
                        "RGBA or built-in scenes); this dataset has none")
  return render_lib.images_on_background(dataset, config)


def make_schedule(train_config):
  """Linear warm-up to `lr`, then exponential decay reaching `lr_final` at `max_steps`."""
  tc = train_config
  decay_steps = max(tc.max_steps - tc.warmup_steps, 1)
  decay = optax.exponential_decay(tc.lr, decay_steps, tc.lr_final / tc.lr)
  if tc.warmup_steps <= 0:
    return decay
  warmup = optax.linear_schedule(0.0, tc.lr, tc.warmup_steps)
  return optax.join_schedules([warmup, decay], [tc.warmup_steps])


def make_optimizer(train_config):
  """Adam on the schedule, with optional global-norm gradient clipping."""
  adam = optax.adam(make_schedule(train_config))
  if train_config.grad_clip > 0:
    return optax.chain(optax.clip_by_global_norm(train_config.grad_clip), adam)
  return adam


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
    if config.train.get("image_order", "random") == "epochs":
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
  else:
    idx = jax.random.randint(key, (config.train.batch_rays,), 0, num_images * num_pixels)
    take = lambda a: a.reshape(-1, *a.shape[2:])[idx]
  return jax.tree_util.tree_map(take, data)


def make_train_step(model, tx, config, near, far, mesh=None):
  """The jitted train step: (state, data, key) -> (state, stats). `state` is donated.

  mesh: a `parallel.make_mesh` Mesh to split each batch over its devices (data and state
  replicated on it), or None for one device.
  """
  fixed_background = jnp.asarray(render_lib.background_colour(config))
  random_background = isinstance(config.data.background, str) and config.data.background == "random"

  def loss_fn(params, batch, key):
    render_key, bg_key = jax.random.split(key)
    background, target = fixed_background, batch.rgb
    if random_background:
      # A fresh background per ray: the field cannot bake the background into density.
      background = jax.random.uniform(bg_key, batch.rgb.shape)
      target = batch.rgb + (1.0 - batch.acc)[:, None] * (background - fixed_background)
    rays = Rays(batch.origins, batch.directions)
    outputs = renderer.render_rays(model, params, rays, config, near, far, render_key,
                                   background, batch.viewdirs)
    mses = {name: jnp.mean((out["rgb"] - target) ** 2) for name, out in outputs.items()}
    loss = mses["coarse"] if "fine" not in mses else (
        mses["fine"] + config.train.coarse_loss_weight * mses["coarse"])
    best = mses.get("fine", mses["coarse"])
    return loss, {"loss": loss, "psnr": metrics.mse_to_psnr(best)}

  def refresh_occupancy(params, step):
    """Recompute the occupancy grid from the density field every `update_every` steps."""
    if not renderer.uses_occupancy(config):
      return params
    every = config.occupancy.update_every
    grid = jax.lax.cond(step % every == 0, lambda p: renderer.occupancy_grid(model, p, config),
                        lambda p: p["occupancy"], params)
    return {**params, "occupancy": grid}

  def step(state, data, run_key):
    key = jax.random.fold_in(run_key, state.step)
    batch_key, render_key = jax.random.split(key)
    batch = parallel.shard_batch(draw_batch(data, config, batch_key, state.step, run_key), mesh)
    params = refresh_occupancy(state.params, state.step)
    grads, stats = jax.grad(loss_fn, has_aux=True)(params, batch, render_key)
    finite = jnp.isfinite(stats["loss"]) & jnp.all(jnp.array(
        [jnp.all(jnp.isfinite(g)) for g in jax.tree_util.tree_leaves(grads)]))
    # The occupancy grid gets a zero gradient, so Adam leaves it as refreshed above.
    updates, opt_state = tx.update(grads, state.opt_state, params)
    params = optax.apply_updates(params, updates)
    # A non-finite step is not applied (the state stays the last good one) and is reported.
    keep = lambda new, old: jax.tree_util.tree_map(lambda n, o: jnp.where(finite, n, o), new, old)
    bad_step = jnp.where((state.bad_step < 0) & ~finite, state.step, state.bad_step)
    new_state = TrainState(step=state.step + 1, params=keep(params, state.params),
                           opt_state=keep(opt_state, state.opt_state), bad_step=bad_step)
    return parallel.replicated_constraint(new_state, mesh), stats

  return jax.jit(step, donate_argnums=0)


_STEPS = collections.OrderedDict()  # the few most recent train steps, see `_cached_train_step`


def _cached_train_step(model, tx, config, near, far, mesh):
  """`make_train_step`, reused for an equal config in the same process (tests, sweeps and
  resumed runs then compile it once): the step depends on nothing else."""
  key = (config.to_json(), float(near), float(far), mesh)
  if key not in _STEPS:
    _STEPS[key] = make_train_step(model, tx, config, near, far, mesh)
    while len(_STEPS) > 4:
      _STEPS.popitem(last=False)
  _STEPS.move_to_end(key)
  return _STEPS[key]


def model_signature(config):
  """Config fields that fix the parameter shapes; a checkpoint only restores under the same."""
  m = config.model
  signature = {"pos_encode_dims": config.pos_encode_dims,
               "dir_encode_dims": config.dir_encode_dims, "depth": m.depth, "width": m.width,
               "skip_layers": list(m.skip_layers), "view_dependent": m.view_dependent,
               "view_width": m.view_width, "networks": list(renderer.network_names(config))}
  if m.get("encoding", "posenc") != "posenc":  # only then, so older checkpoints stay valid
    signature.update(encoding=m.encoding, grid_resolutions=list(m.grid_resolutions),
                     grid_features=m.grid_features)
  if renderer.uses_occupancy(config):
    signature.update(occupancy_resolution=config.occupancy.resolution)
  return signature


def state_template(model, tx, config):
  """The structure of `init_state` (shapes and dtypes, nothing computed): what a checkpoint
  restores into, in a fraction of a second instead of initialising every parameter eagerly."""
  return jax.eval_shape(lambda: init_state(model, tx, config))


def init_state(model, tx, config):
  params = renderer.init_params(model, config, jax.random.PRNGKey(config.seed))
  return TrainState(step=jnp.array(0, jnp.int32), params=params, opt_state=tx.init(params),
                    bad_step=jnp.array(-1, jnp.int32))


def bounds(config, dataset):
  """(near, far): [0, 1] in NDC, else the config's overrides where set, else the dataset's."""
  if config.data.get("ndc", False):
    return 0.0, 1.0  # NDC rays run from the near plane (0) to infinity (1)
  return (config.data.near or dataset.near, config.data.far or dataset.far)


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


def _rays_per_step(config, dataset):
  tc = config.train
  if tc.batching == "images":
    return tc.images_per_step * dataset.height * dataset.width
  return tc.batch_rays


def train_and_evaluate(config, workdir):
  """Train on `config.data`, checkpoint into `workdir`, evaluate the test views at the end.

  Resumes from the newest checkpoint in `workdir`. Returns the final metrics dict (also written to
  `workdir/metrics.json`). Writes metrics.jsonl and TensorBoard events (workdir/tb) at log steps.
  """
  main = parallel.is_main_process()
  os.makedirs(workdir, exist_ok=True)
  train_ds, test_ds = loaders.load_dataset(config.data)
  near, far = bounds(config, train_ds)
  model = make_model(config.model)
  tx = make_optimizer(config.train)
  signature = model_signature(config)
  ckpt = checkpoints.latest_path(workdir)
  elapsed = 0.0
  if not ckpt:
    state = init_state(model, tx, config)
  else:
    state, meta = checkpoints.restore_with_meta(ckpt, state_template(model, tx, config),
                                                signature)
    elapsed = float(meta.get("wall_seconds", 0.0))
    if main:
      print(f"resuming from {ckpt} at step {int(state.step)}", flush=True)
  if main:
    checkpoints.atomic_write(os.path.join(workdir, "config.json"),
                             config.to_json(indent=2).encode())

  tc = config.train
  mesh = parallel.make_mesh(tc.get("data_parallel", True))
  rays_per_step = _rays_per_step(config, train_ds)
  parallel.check_batch(rays_per_step, mesh)
  data = parallel.replicate(make_train_data(train_ds, config), mesh)
  state = parallel.replicate(state, mesh)
  train_step = _cached_train_step(model, tx, config, near, far, mesh)
  evaluate = render_lib.make_evaluator(model, config, near, far, test_ds)
  schedule = make_schedule(tc)
  writer = summary.Writer(workdir, enabled=main and tc.get("tensorboard", True))
  key = jax.random.PRNGKey(config.seed + 1)
  start_step = int(state.step)
  t_start = time.perf_counter() - elapsed
  last_log, last_log_step = time.perf_counter(), start_step
  step = start_step
  bar = progress.Progress(tc.max_steps, "train", start=start_step,
                          stream=None if main else io.StringIO())
  viewer = live_viewer.start(config, model, near, far, train_ds, workdir, enabled=main)
  with _StopRequest() as stop:
    while step < tc.max_steps:
      state, stats = train_step(state, data, key)
      step += 1
      viewer.after_step(step, lambda: _one_device(state.params, mesh))
      budget_over = tc.max_seconds > 0 and time.perf_counter() - t_start >= tc.max_seconds
      log_now = step % tc.log_every == 0 or step == tc.max_steps or budget_over or stop.signum
      if log_now:
        stats = jax.device_get(stats)
        _check_finite(state, workdir)
        now = time.perf_counter()
        rays_s = (step - last_log_step) * rays_per_step / max(now - last_log, 1e-9)
        last_log, last_log_step = now, step
        wall = now - t_start
        record = {"step": step, "wall_seconds": round(wall, 3), "loss": float(stats["loss"]),
                  "train_psnr": float(stats["psnr"]), "rays_per_second": round(rays_s)}
        if tc.eval_every and step % tc.eval_every == 0:
          images = {}
          record["eval_psnr"] = float(evaluate(
              _one_device(state.params, mesh), max_views=tc.eval_views,
              on_view=_first_view_into(images, near, far))["psnr"])
          writer.images(step, images)
        if main:
          _log(workdir, record)
        writer.scalars(step, {"train/loss": record["loss"], "train/psnr": record["train_psnr"],
                              "train/learning_rate": float(schedule(step - 1)),
                              "train/rays_per_second": rays_s,
                              **({"eval/psnr": record["eval_psnr"]}
                                 if "eval_psnr" in record else {})})
        eta = (tc.max_steps - step) * wall / max(step - start_step, 1)
        if tc.max_seconds > 0:
          eta = min(eta, tc.max_seconds - wall)
        bar.update(step, info=f"loss {record['loss']:.5f} psnr {record['train_psnr']:.2f}")
        bar.write(f"step {step}/{tc.max_steps} loss {record['loss']:.5f} "
                  f"psnr {record['train_psnr']:.2f} {rays_s:,.0f} rays/s "
                  f"elapsed {progress.format_seconds(wall)} eta {progress.format_seconds(eta)}")
      elif bar.due():
        jax.block_until_ready(state.step)  # show steps done, not steps queued (a scalar sync)
        bar.update(step)
      if step % tc.checkpoint_every == 0 or step == tc.max_steps or budget_over or stop.signum:
        _check_finite(state, workdir)  # never checkpoint a state that has seen a bad step
        _save(workdir, state, signature, tc.keep_checkpoints, time.perf_counter() - t_start)
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
  params = _one_device(state.params, mesh)
  images = {}
  result = evaluate(params, out_dir=os.path.join(workdir, "eval")
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
                 "eval_psnr": result["psnr"], "eval_ssim": result["ssim"], "final": True})
  print(f"test PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.4f} over "
        f"{len(result['per_view'])} views after {step} steps ({train_seconds:.0f} s)", flush=True)
  if config.render.after_training:
    render_lib.render_video(model, params, config, near, far,
                            train_ds, os.path.join(workdir, "video"))
  return result


def _one_device(params, mesh):
  """Parameters for rendering on one device (a replicated copy would render on every device)."""
  if mesh is None:
    return params
  return jax.device_put(parallel.to_host(params), jax.local_devices()[0])


def _first_view_into(images, near, far):
  """An evaluator `on_view` callback putting the first view's TensorBoard images in `images`."""
  def on_view(index, out, truth):
    if index == 0:
      images.update({"eval/rgb": render_lib.to_uint8(out["rgb"]),
                     "eval/depth": render_lib.colorize(out["depth"], near, far),
                     "eval/truth": render_lib.to_uint8(truth)})
  return on_view


def _save(workdir, state, signature, keep, elapsed):
  """Checkpoint `state` (process 0 only), with the wall seconds spent so far in its meta."""
  host_state = parallel.to_host(state)
  if parallel.is_main_process():
    checkpoints.save(workdir, int(host_state.step), host_state, signature, keep,
                     meta={"wall_seconds": elapsed})


def _check_finite(state, workdir):
  bad = int(state.bad_step)
  if bad >= 0:
    last = checkpoints.latest_path(workdir) or "none yet"
    raise TrainingError(f"non-finite loss or gradient at step {bad + 1}; the update was not "
                        f"applied; last good checkpoint: {last}. Try a lower config.train.lr "
                        "or set config.train.grad_clip.")


def load_config_json(workdir):
  """The ConfigDict a run saved in `workdir/config.json`."""
  path = os.path.join(workdir, "config.json")
  if not os.path.exists(path):
    raise TrainingError(f"{path} not found: is {workdir} a training workdir?")
  with open(path) as f:
    return ml_collections.ConfigDict(json.load(f))
