"""Training, the job: `train_and_evaluate` reads the config, builds the run (experiment.py) and
the jitted step (train_step.py), hands them to the loop with its hooks (train/loop.py,
train/hooks.py), then scores the test views; and the time budget fitted for it and for the
benchmark (`fit_to_time`).

With several processes only process 0 reads and writes the workdir.
"""

import collections
import dataclasses
import functools
import io
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import ml_collections

from nerf_jax.backend import determinism
from nerf_jax.evaluate import lpips
from nerf_jax.run import (builders, config_lib, experiment, experiment_parts, machine,
                          outputs)
from nerf_jax.run.auto import auto
from nerf_jax.run.experiment import TrainingError
from nerf_jax.run.signature import init_state, model_signature, state_template
from nerf_jax.train import (budget, checkpoints, hooks as hooks_lib, loop, optimizer, parallel,
                            progress, summary, train_step as train_step_lib)
from nerf_jax.train.state import upgrade_state_dict

_STEPS = collections.OrderedDict()  # the few most recent train steps (see `train_and_evaluate`)


def train_and_evaluate(config, workdir, watchers=()):
  """Train on `config.data`, checkpoint into `workdir`, evaluate the test views at the end.

  Resumes from the newest checkpoint in `workdir`. Returns the final metrics dict (also written to
  `workdir/metrics.json`). Writes metrics.jsonl and TensorBoard events (workdir/tb) at log steps.
  The run lasts train.max_steps steps if set, else until train.max_seconds with the schedule
  fitted to the steps expected in it (budget.py), else train.default_steps steps; the run's
  config.json holds the schedule it used. SIGINT or SIGTERM saves a checkpoint, then raises
  KeyboardInterrupt.

  watchers: what watches the run from outside the loop, each given as a factory fn(exp,
  workdir, main) -> watcher (exp: the run's experiment_parts.Experiment; main: whether this is
  process 0), called once the run is set up; a watcher has after_step(step, variables_fn),
  called after every step (variables_fn() -> the current variables on one device), and
  close(), called after the last step; the loop runs each through a hooks.Watch hook.
  nerf-train passes the live viewer's (viewer/training.start).
  """
  config = config_lib.upgrade(config)
  if config.train.deterministic:
    determinism.require()  # before the first computation starts jax's backends
  main = parallel.is_main_process()
  sampler = machine.Sampler()  # the machine's load over the run: metrics.json's 'machine'
  parallel.check_time_budget(config.train.max_seconds)
  if main:
    os.makedirs(workdir, exist_ok=True)
  exp = experiment.setup(config)
  exp, waiting = _step_rule_at_start(exp, workdir)
  signature = model_signature(exp.config)  # as resolved from the data (config.auto, ...)
  state, meta = _start_state(exp, workdir, signature)
  # The run's seconds, a resumed run's earlier ones included (a time budget's calibration
  # counts against it).
  t_start = time.perf_counter() - float(meta.get("wall_seconds", 0.0))
  elapsed = lambda: time.perf_counter() - t_start
  mesh = parallel.make_mesh(exp.config.train.data_parallel)
  parallel.check_batch(builders.rays_per_step(exp.config, exp.train_ds), mesh)
  data = parallel.replicate(builders.make_train_data(exp), mesh)
  key = jax.random.PRNGKey(exp.config.seed + 1)
  # Reused for an equal run in the same process (tests, sweeps and resumed runs compile once).
  train_step = _train_step(exp, mesh)
  config, last_step = exp.config, builders.schedule_steps(exp.config.train)
  if fits_time(config.train):
    max_seconds = config.train.max_seconds

    def fit(run):  # `run`'s schedule fitted, on its own data and step (the decided run's built)
      nonlocal data, train_step
      if run is not exp:
        data = parallel.replicate(builders.make_train_data(run), mesh)
        train_step = _train_step(run, mesh)
      return _resumed_or_fitted(run, train_step, data, key, mesh, meta, t_start)

    exp, config, refitted = fit_then_decide(exp, waiting, fit, lambda _: max_seconds - elapsed())
    if refitted:  # an effect the step rule kept on: its model and state
      signature = model_signature(exp.config)
      state = parallel.from_main(init_state(exp))
    train_step = functools.partial(train_step, planned_steps=jnp.int32(config.train.max_steps))
    last_step = sys.maxsize  # the clock ends the run
  if main:  # with the schedule the run uses
    # Registered names as their module paths: a restore in a new process finds them again.
    checkpoints.atomic_write(os.path.join(workdir, "config.json"),
                             builders.portable(config).to_json(indent=2).encode())
  state = parallel.replicate(state, mesh)
  writer = summary.Writer(workdir, enabled=main and config.train.tensorboard)
  evaluate = builders.make_evaluator(exp)
  loop_hooks = _loop_hooks(exp, config, workdir, signature, evaluate, writer, mesh,
                          int(state.step), last_step, elapsed)
  loop_hooks = [hooks_lib.Watch(make_watcher(exp, workdir, main), _variables_on(mesh))
                for make_watcher in watchers] + loop_hooks  # the caller's, after every step
  out_of_time = lambda: 0 < config.train.max_seconds <= elapsed()
  # A run the clock can end keeps one step queued: the clock counts steps done (loop.run).
  state, step, signum = loop.run(state, lambda s: train_step(s, data, key), loop_hooks,
                                 int(state.step), last_step, out_of_time,
                                 in_flight=1 if config.train.max_seconds > 0 else None)
  if signum:
    raise KeyboardInterrupt(f"stopped by signal {signum} at step {step}; "
                            f"checkpoint saved in {checkpoints.checkpoint_dir(workdir)}")
  rate = next((h.rays_per_second for h in loop_hooks if isinstance(h, hooks_lib.Record)), None)
  return _finish(exp, config, workdir, state, step, evaluate, writer, mesh, elapsed(), rate,
                 sampler)


def _train_step(exp, mesh):
  """The jitted train step of `exp` on `mesh`, compiled once for an equal run in the same
  process (tests, sweeps and resumed runs)."""
  cached = (exp.config.to_json(), exp.near, exp.far, mesh)
  if cached not in _STEPS:
    _keep(cached, train_step_lib.make_train_step(**builders.train_step_args(exp, mesh)))
  _STEPS.move_to_end(cached)
  return _STEPS[cached]


def _step_rule_at_start(exp, workdir):
  """(Experiment, waiting): auto's step rule (with_step_rule) decided where it can be before
  the state is built: as the run that `workdir` resumes decided it (its config.json; process 0
  reads the workdir), (decided Experiment, None); a new run's as step_rule_before_fit."""
  if not exp.config.auto_by_steps:
    return exp, None
  if parallel.is_main_process() and checkpoints.latest_path(workdir):
    saved = config_lib.load_saved(workdir)
    config = ml_collections.ConfigDict(exp.config.to_dict())
    for name in exp.config.auto_by_steps:
      config_lib.set_field(config, name, config_lib.get_field(saved, name))
    config.auto_by_steps, config.auto_decisions = (), saved.auto_decisions
    return experiment_parts.assemble(config, exp.train_ds, exp.test_ds, exp.near, exp.far,
                                     exp.hull), None
  return step_rule_before_fit(exp, fits_time(exp.config.train))


def with_step_rule(exp, steps, quiet=False):
  """`exp` rebuilt on its config with auto's step rule decided at `steps` (auto.by_steps: the
  effects that pay only from more steps off, the record cleared, one printed line each unless
  `quiet`; the same data and bounds); `exp` itself where nothing waits (config.auto_by_steps)."""
  if not exp.config.auto_by_steps:
    return exp
  config, lines = auto.by_steps(exp.config, steps)
  for line in lines if not quiet else ():
    print(f"auto: {line}", flush=True)
  return experiment_parts.assemble(config, exp.train_ds, exp.test_ds, exp.near, exp.far,
                                   exp.hull)


def step_rule_before_fit(exp, fitted):
  """(Experiment, waiting): auto's step rule (with_step_rule) for a new run: decided on the step
  budget where the schedule is not `fitted` to a time budget, (decided Experiment, None); else
  fitted with the waiting effects off, (`exp` with them off, `exp`), decided by
  fit_then_decide. (`exp`, None) where nothing waits (config.auto_by_steps)."""
  if not exp.config.auto_by_steps:
    return exp, None
  if not fitted:
    return with_step_rule(exp, builders.schedule_steps(exp.config.train)), None
  return with_step_rule(exp, 0, quiet=True), exp


def fit_then_decide(exp, waiting, fit, seconds_left):
  """(Experiment, config, refitted): a time budget's schedule fitted, then auto's step rule
  decided on the steps it holds (training and the benchmark alike).

  fit(exp) -> a copy of exp.config with the steps that fit in the budget (fit_to_time);
  waiting: the Experiment whose effects wait for the rule (step_rule_before_fit), or None;
  seconds_left(fit_seconds) -> the budget's seconds left after a fit that took `fit_seconds`.
  The rule is decided on the steps that remain after another fit as long
  (steps_after_another_fit): where it keeps an effect on, that run is refitted (its own step
  compiled) and returned with refitted=True; else `exp` as fitted, with the decided record
  (config.auto_decisions).
  """
  fit_start = time.perf_counter()
  config = fit(exp)
  if waiting is None:
    return exp, config, False
  fit_seconds = time.perf_counter() - fit_start
  decided = with_step_rule(waiting, steps_after_another_fit(
      config.train.max_steps, seconds_left(fit_seconds), fit_seconds))
  if kept_on(decided.config, waiting.config):  # one pays: its step compiled, refitted
    return decided, fit(decided), True
  config.auto_by_steps, config.auto_decisions = (), decided.config.auto_decisions
  return dataclasses.replace(exp, config=decided.config), config, False


def steps_after_another_fit(steps, seconds_left, fit_seconds):
  """The steps of `steps` fitted into `seconds_left` that remain after a fit as long as the last
  one (`fit_seconds`: compiling and timing a step) is spent again: what a time budget holds
  for an effect whose own step must still be compiled (a capture.py step on a loaded CPU
  core compiles in ~30 s: 83 steps of a 60 s budget become 26)."""
  return int(steps * max(seconds_left - fit_seconds, 0.0) / max(seconds_left, 1e-9))


def kept_on(decided, waiting):
  """Whether the step rule kept on an effect of the ConfigDict `waiting` (auto_by_steps) in the
  ConfigDict `decided`."""
  return any(config_lib.get_field(decided, name) == config_lib.get_field(waiting, name)
             for name in waiting.auto_by_steps)


def _keep(cached, train_step):
  """Remember `train_step` under `cached`, keeping the 4 most recent."""
  _STEPS[cached] = train_step
  while len(_STEPS) > 4:
    _STEPS.popitem(last=False)


def _loop_hooks(exp, config, workdir, signature, evaluate, writer, mesh, start_step, last_step,
                elapsed):
  """The loop's hooks of a run of `config` (train/hooks.py), in the order they run."""
  tc, main = config.train, parallel.is_main_process()
  window = progress.RateWindow(start_step)  # steps per second of training alone
  variables = _variables_on(mesh)
  check = lambda state: _check_finite(state, workdir)
  save = lambda state: _save(workdir, state, signature, tc, elapsed())
  clocked = last_step == sys.maxsize  # a time budget: the clock, not a step count, is the total
  found = [
      hooks_lib.Record(tc.log_every, window, builders.rays_per_step(config, exp.train_ds),
                       elapsed, check),
      hooks_lib.Evaluate(tc.eval_every,
                         lambda v, on_view: evaluate(v, max_views=tc.eval_views, on_view=on_view),
                         variables, window, writer, exp.near, exp.far),
      hooks_lib.MetricsFile(os.path.join(workdir, "metrics.jsonl")) if main else None,
      hooks_lib.TensorBoard(writer, optimizer.make_schedule(builders.optimizer_settings(config))),
      hooks_lib.ProgressLine(builders.schedule_steps(tc), tc.max_seconds, clocked, start_step,
                             elapsed, stream=None if main else io.StringIO()),
      hooks_lib.Checkpoint(tc.checkpoint_every, window, check, save)]
  return [hook for hook in found if hook is not None]


def _finish(exp, config, workdir, state, step, evaluate, writer, mesh, train_seconds,
            rays_per_second=None, sampler=None):
  """After the last step: score the test views (their images into workdir/eval with
  render.after_training), write metrics.json and the final metrics.jsonl record, render the
  video; returns the final metrics. A long evaluation (+ video) is announced first, with how to
  shorten it (outputs.final_render_line, from the training's last rays_per_second). sampler:
  the run's machine.Sampler, stopped here (the load while training) for metrics.json."""
  main = parallel.is_main_process()
  measured = sampler.stop() if sampler else None
  if measured and train_seconds > 0:  # the run's own rates beside the load it ran under
    measured.update(machine.rates(step, config.train.batch_rays, train_seconds))
  _check_finite(state, workdir)
  line = outputs.final_render_line(exp, rays_per_second) if main else None
  if line:
    print(line, flush=True)
  variables = _variables_on(mesh)(state)
  images = {}
  result = evaluate(
      variables, out_dir=os.path.join(workdir, "eval")
      if config.render.after_training and main else None,
      on_view=hooks_lib.first_view_into(images, exp.near, exp.far))
  writer.images(step, images)
  writer.scalars(step, {"test/psnr": result["psnr"], "test/ssim": result["ssim"]})
  writer.close()
  result.update(train_seconds=round(train_seconds, 3), steps=step)
  if not main:
    return result
  # With the background the views were scored on (data.background, 'auto' resolved), and the
  # machine the run trained on (machine.py).
  checkpoints.atomic_write(os.path.join(workdir, "metrics.json"), json.dumps(
      {**result, "background": config.data.background,
       **({"machine": measured} if measured else {})}, indent=2).encode())
  hooks_lib.append_json_line(os.path.join(workdir, "metrics.jsonl"), {
      "step": step, "wall_seconds": round(train_seconds, 3), "eval_psnr": result["psnr"],
      "eval_ssim": result["ssim"], **({"eval_lpips": result["lpips"]} if "lpips" in result else {}),
      "final": True})
  print(f"test PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.4f}, {lpips.describe(result)} "
        f"over {len(result['per_view'])} views after {step} steps ({train_seconds:.0f} s)"
        f"{machine.busy_note(measured)}", flush=True)
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
    state, meta = init_state(exp), {}
  else:
    state, meta = checkpoints.restore_with_meta(ckpt, state_template(exp), signature,
                                                upgrade_state_dict)
    print(f"resuming from {ckpt} at step {int(state.step)}", flush=True)
  return parallel.from_main(state), meta


def fits_time(train_config):
  """Whether the step budget and schedule follow from the time budget (max_seconds > 0 and no
  max_steps of the user's)."""
  return train_config.max_seconds > 0 and not train_config.max_steps


def fit_schedule(train_config, num_steps):
  """Set max_steps = num_steps (in place); warm-up keeps its share of the planned steps."""
  share = train_config.warmup_steps / max(builders.schedule_steps(train_config), 1)
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
  state = parallel.replicate(init_state(exp), mesh)
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


def _variables_on(mesh):
  """state -> its variables for rendering on one device (a copy replicated on `mesh` would
  render on every device)."""
  if mesh is None:
    return lambda state: state.variables
  return lambda state: jax.device_put(parallel.to_host(state.variables), jax.local_devices()[0])


def _save(workdir, state, signature, train_config, elapsed):
  """Checkpoint `state` (process 0 only); its meta holds the wall seconds spent so far and the
  schedule (a time-budget run resumes on the schedule it fitted)."""
  host_state = parallel.to_host(state)
  if parallel.is_main_process():
    checkpoints.save(workdir, int(host_state.step), host_state, signature,
                     train_config.keep_checkpoints,
                     meta={"wall_seconds": elapsed,
                           "schedule_steps": builders.schedule_steps(train_config),
                           "warmup_steps": int(train_config.warmup_steps)})


def _check_finite(state, workdir):
  bad = int(state.bad_step)
  if bad >= 0:
    last = checkpoints.latest_path(workdir) or "none yet"
    raise TrainingError(f"non-finite loss or gradient at step {bad + 1}; the update was not "
                        f"applied; last good checkpoint: {last}. Try a lower config.train.lr "
                        "or set config.train.grad_clip.")
