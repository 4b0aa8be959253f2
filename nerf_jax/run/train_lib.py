"""Training: the loop of `train_and_evaluate` (logs, checkpoints, evaluations, signals) and
the time budget fitted for it and for the benchmark (`fit_to_time`).

The batches are train_batches.py, the jitted step train_step.py, the evaluator evaluation.py.
With several processes only process 0 reads and writes the workdir.
"""

import functools
import io
import json
import os
import signal
import sys
import time

import jax
import jax.numpy as jnp
import ml_collections

from nerf_jax.backend import determinism
from nerf_jax.evaluate import lpips, visuals
from nerf_jax.run import config_lib, experiment, outputs
from nerf_jax.train import budget, checkpoints, parallel, progress, summary
from nerf_jax.run.experiment import TrainingError, TrainState  # noqa: F401  (re-exported)


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


def train_and_evaluate(config, workdir, hooks=()):
  """Train on `config.data`, checkpoint into `workdir`, evaluate the test views at the end.

  Resumes from the newest checkpoint in `workdir`. Returns the final metrics dict (also written to
  `workdir/metrics.json`). Writes metrics.jsonl and TensorBoard events (workdir/tb) at log steps.
  The run lasts train.max_steps steps if set, else until train.max_seconds with the schedule
  fitted to the steps expected in it (budget.py), else train.default_steps steps; the run's
  config.json holds the schedule it used.

  hooks: step hooks, each given as a factory fn(exp, workdir, main) -> hook (exp: the run's
  experiment.Experiment; main: whether this is process 0), called once the run is set up; a
  hook has after_step(step, variables_fn), called after every step (variables_fn() -> the
  current variables on one device), and close(), called after the last step. nerf-train passes
  the live viewer's (viewer/training.start).
  """
  config = config_lib.upgrade(config)
  if config.train.deterministic:
    determinism.require()  # before the first computation starts jax's backends
  main = parallel.is_main_process()
  parallel.check_time_budget(config.train.max_seconds)
  if main:
    os.makedirs(workdir, exist_ok=True)
  exp = experiment.setup(config)
  config = exp.config  # as resolved from the data (config.auto, data.scene_bound = -1)
  near, far = exp.near, exp.far
  signature = experiment.model_signature(config)
  state, meta = _start_state(exp, workdir, signature)
  elapsed = float(meta.get("wall_seconds", 0.0))
  t_start = time.perf_counter() - elapsed  # a time budget's calibration counts against it

  mesh = parallel.make_mesh(config.train.data_parallel)
  step_rays = experiment.rays_per_step(config, exp.train_ds)
  parallel.check_batch(step_rays, mesh)
  data = parallel.replicate(experiment.make_train_data(exp), mesh)
  key = jax.random.PRNGKey(config.seed + 1)
  train_step = experiment.cached_train_step(exp, mesh)
  last_step = experiment.schedule_steps(config.train)
  if fits_time(config.train):
    config = _resumed_or_fitted(exp, train_step, data, key, mesh, meta, t_start)
    planned = jnp.int32(config.train.max_steps)
    train_step = functools.partial(train_step, planned_steps=planned)
    last_step = sys.maxsize  # the clock ends the run
  if main:  # with the schedule the run uses
    checkpoints.atomic_write(os.path.join(workdir, "config.json"),
                             config.to_json(indent=2).encode())
  tc = config.train
  state = parallel.replicate(state, mesh)
  evaluate = experiment.make_evaluator(exp)
  schedule = experiment.make_schedule(tc)
  writer = summary.Writer(workdir, enabled=main and tc.tensorboard)
  start_step = int(state.step)
  window = progress.RateWindow(start_step)  # steps per second of training alone
  step = start_step
  planned = experiment.schedule_steps(tc)
  clocked = last_step == sys.maxsize  # a time budget: the clock, not a step count, is the total
  position = lambda: int(time.perf_counter() - t_start) if clocked else step
  bar = progress.Progress(int(tc.max_seconds) if clocked else planned,
                          "train (seconds)" if clocked else "train", start=position(),
                          stream=None if main else io.StringIO())
  hooks = [make_hook(exp, workdir, main) for make_hook in hooks]
  with _StopRequest() as stop:
    while step < last_step:
      state, stats = train_step(state, data, key)
      step += 1
      for hook in hooks:
        hook.after_step(step, lambda: _one_device(state.variables, mesh))
      budget_over = tc.max_seconds > 0 and time.perf_counter() - t_start >= tc.max_seconds
      log_now = step % tc.log_every == 0 or step == last_step or budget_over or stop.signum
      if log_now:
        # The window ends when the device has done every step dispatched (module RateWindow).
        state, stats = jax.block_until_ready((state, stats))
        rays_s = window.rate(step) * step_rays
        stats = jax.device_get(stats)
        _check_finite(state, workdir)
        wall = time.perf_counter() - t_start
        record = {"step": step, "wall_seconds": round(wall, 3), "loss": float(stats["loss"]),
                  "train_psnr": float(stats["colour/psnr"]), "rays_per_second": round(rays_s)}
        # Whatever else the loss terms report (train/losses/), as '<term>/<stat>': e.g. a
        # sample budget's colour/rays_in_loss, the rays it held whole this step.
        extra = {name: value.item() for name, value in stats.items()
                 if name not in ("loss", "colour/psnr")}
        record.update(extra)
        if tc.eval_every and step % tc.eval_every == 0:
          images = {}
          with window.excluded():
            record["eval_psnr"] = float(evaluate(
                _one_device(state.variables, mesh), max_views=tc.eval_views,
                on_view=_first_view_into(images, near, far))["psnr"])
            writer.images(step, images)
        if main:
          _log(workdir, record)
        writer.scalars(step, {"train/loss": record["loss"], "train/psnr": record["train_psnr"],
                              "train/learning_rate": float(schedule(step - 1)),
                              "train/rays_per_second": rays_s,
                              **{f"train/{name}": value for name, value in extra.items()},
                              **({"eval/psnr": record["eval_psnr"]}
                                 if "eval_psnr" in record else {})})
        eta = max(planned - step, 0) * wall / max(step - start_step, 1)
        if tc.max_seconds > 0:
          eta = max(min(eta, tc.max_seconds - wall), 0.0)
        of = f" of {progress.format_seconds(tc.max_seconds)}" if clocked else ""
        bar.update(position(), info=f"loss {record['loss']:.5f} psnr {record['train_psnr']:.2f}")
        bar.write(f"step {step}{'' if clocked else f'/{planned}'} loss {record['loss']:.5f} "
                  f"psnr {record['train_psnr']:.2f} {rays_s:,.0f} rays/s "
                  f"elapsed {progress.format_seconds(wall)}{of} "
                  f"eta {progress.format_seconds(eta)}")
      elif bar.due():
        jax.block_until_ready(state.step)  # show steps done, not steps queued (a scalar sync)
        bar.update(position())
      if step % tc.checkpoint_every == 0 or step == last_step or budget_over or stop.signum:
        with window.excluded():
          _check_finite(state, workdir)  # never checkpoint a state that has seen a bad step
          _save(workdir, state, signature, tc, time.perf_counter() - t_start)
      if stop.signum:
        bar.close()
        raise KeyboardInterrupt(f"stopped by signal {stop.signum} at step {step}; "
                                f"checkpoint saved in {checkpoints.checkpoint_dir(workdir)}")
      if budget_over:
        break
  bar.close()
  for hook in hooks:
    hook.close()
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
  if config.render.after_training and config.render.video_frames > 0:
    missing = outputs.video_writer_missing()
    if missing:  # the run and its scores are kept; only the video is not
      print(f"{missing}; skipped the video", flush=True)
    else:
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


def fits_time(train_config):
  """Whether the step budget and schedule follow from the time budget (max_seconds > 0 and no
  max_steps of the user's)."""
  return train_config.max_seconds > 0 and not train_config.max_steps


def fit_schedule(train_config, num_steps):
  """Set max_steps = num_steps (in place); warm-up keeps its share of the planned steps."""
  share = train_config.warmup_steps / max(experiment.schedule_steps(train_config), 1)
  train_config.warmup_steps = int(round(share * num_steps))
  train_config.max_steps = int(num_steps)


def fit_to_time(exp, train_step, data, key, seconds_left, mesh=None):
  """A copy of exp.config whose step budget and schedule fit the time left (budget.py): for
  training and the benchmark alike.

  train_step: the jitted step of train_step.make_train_step (with a traced planned_steps, so
  the step it compiles here is the one the run uses). It is timed on a throwaway fresh state
  for budget.CALIBRATION_SECONDS (or that share of train.max_seconds, if less);
  seconds_left(compile_seconds) -> the seconds the run then has for its steps.
  """
  config = ml_collections.ConfigDict(exp.config.to_dict())
  tc = config.train
  state = parallel.replicate(experiment.init_state(exp), mesh)
  seconds = min(budget.CALIBRATION_SECONDS, budget.CALIBRATION_SHARE * tc.max_seconds)
  step_seconds, compile_seconds = budget.calibrate(
      lambda s: train_step(s, data, key, planned_steps=jnp.int32(1))[0], state, seconds)
  fit_schedule(tc, budget.steps_in(seconds_left(compile_seconds), step_seconds, 0.0))
  return config


def _resumed_or_fitted(exp, train_step, data, key, mesh, meta, t_start):
  """A resumed run's config with the schedule its checkpoint `meta` recorded (the one it
  started with); a new run's fitted to what is left of train.max_seconds since `t_start`."""
  if "schedule_steps" not in meta:
    left = lambda _: exp.config.train.max_seconds - (time.perf_counter() - t_start)
    return fit_to_time(exp, train_step, data, key, left, mesh)
  config = ml_collections.ConfigDict(exp.config.to_dict())
  config.train.max_steps = int(meta["schedule_steps"])
  config.train.warmup_steps = int(meta["warmup_steps"])
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
      images.update({"eval/rgb": visuals.to_uint8(out["rgb"]),
                     "eval/depth": visuals.colorize(out["depth"], near, far),
                     "eval/truth": visuals.to_uint8(truth)})
  return on_view


def _save(workdir, state, signature, train_config, elapsed):
  """Checkpoint `state` (process 0 only); its meta holds the wall seconds spent so far and the
  schedule (a time-budget run resumes on the schedule it fitted)."""
  host_state = parallel.to_host(state)
  if parallel.is_main_process():
    checkpoints.save(workdir, int(host_state.step), host_state, signature,
                     train_config.keep_checkpoints,
                     meta={"wall_seconds": elapsed,
                           "schedule_steps": experiment.schedule_steps(train_config),
                           "warmup_steps": int(train_config.warmup_steps)})


def _check_finite(state, workdir):
  bad = int(state.bad_step)
  if bad >= 0:
    last = checkpoints.latest_path(workdir) or "none yet"
    raise TrainingError(f"non-finite loss or gradient at step {bad + 1}; the update was not "
                        f"applied; last good checkpoint: {last}. Try a lower config.train.lr "
                        "or set config.train.grad_clip.")
