"""One configuration trained under the benchmark's clock and measured: its record.

The run is built and stepped by the library (experiment.setup / init_state /
make_train_data / make_train_step / make_evaluator, Experiment.camera; the time budget
fitted by train_lib.fit_to_time, as for training); only
the loop around the step is the bench's own: it syncs once per segment of steps, times the
segments, and probes PSNR with the clock paused (see measure.py for the time words), which is
not what train_lib.train_and_evaluate measures.

Run alone, `python -m nerf_jax.bench.timed_run SPEC.json` is the subprocess of one run of a
sweep (see runner.py): it reads {'config', 'options', 'record_path'} and writes the record there.
"""

import dataclasses
import json
import math
import sys
import time
import traceback

import jax
import numpy as np

from nerf_jax.evaluate import evaluation
from nerf_jax.render import background, image_renderer
from nerf_jax.run import builders, experiment, machine
from nerf_jax.train import optimizer
from nerf_jax.run.signature import init_state
from nerf_jax.run import train_lib
from nerf_jax.bench import measure, sweeps

SEGMENT_SECONDS = 0.25  # steps between host syncs: about this long (bounds budget overshoot)
MAX_SEGMENT_STEPS = 64
RENDER_PIXELS = 100 * 100  # render time is reported per frame of this many pixels


@dataclasses.dataclass
class Options:
  """How each run is measured (the config says what is trained and for how long)."""
  eval_times: tuple = (15, 30, 60, 120, 300, 600)  # train seconds at which to probe PSNR
  eval_views: int = 1  # test views per probe (the final metrics use all)
  render_repeats: int = 5  # timed renders of a frame, after one warm-up
  matmul_repeats: int = 10  # timed matmuls per shape for the machine's peak
  fit_schedule: bool = True  # budget mode: stretch the lr schedule to the steps that fit
  eval_dir: str = ""  # write the final test views here ([prediction | depth | truth] PNGs)


def train_loop(step_fn, state, max_steps, max_seconds, probe_times, probe, clock):
  """Step until `max_steps`, or until `clock` passes `max_seconds` (> 0); probe on the way.

  step_fn: state -> (state, stats), may return before the work is done; the loop syncs once
  per segment of steps (about SEGMENT_SECONDS long) and times the segment. probe: state ->
  PSNR, run with the clock paused at the last sync expected before each of `probe_times`
  (train seconds); a probe also records the stats of the step before it (`step_stats`).
  Returns (state, steps, segments [(steps, seconds)], probes [{'seconds', 'step', 'psnr',
  'train'}], the last step's stats).
  """
  pending = sorted(probe_times)
  segments, probes, step, size, stats = [], [], 0, 1, {}
  while step < max_steps and not (max_seconds > 0 and clock.seconds() >= max_seconds):
    size = min(size, max_steps - step)
    start = time.perf_counter()
    for _ in range(size):
      state, stats = step_fn(state)
    jax.block_until_ready(state)
    seconds = time.perf_counter() - start
    segments.append((size, seconds))
    step += size
    per_step = seconds / size
    size = int(np.clip(SEGMENT_SECONDS / per_step, 1, MAX_SEGMENT_STEPS))
    # When the next sync should fall, with half a segment to spare for noisy step times.
    horizon = clock.seconds() + 1.5 * size * per_step
    if pending and pending[0] <= horizon:
      now = clock.seconds()
      pending = [t for t in pending if t > horizon]
      with clock.paused():
        probes.append({"seconds": now, "step": step, "psnr": float(probe(state)),
                       "train": step_stats(stats)})
  return state, step, segments, probes, step_stats(stats)


def step_stats(stats):
  """A train step's stats (train/losses/: loss, colour/psnr, a sample budget's
  colour/rays_in_loss and colour/samples_wanted...) as Python numbers."""
  return {name: jax.device_get(value).item() for name, value in stats.items()}


def _build(exp):
  """(the library's jitted train step, a fresh TrainState) of `exp`. The step donates its state,
  so every loop needs a state of its own."""
  # One compiled init instead of dozens of eagerly compiled small ops: same values, less setup.
  state = jax.jit(lambda: init_state(exp))()
  return builders.make_train_step(exp), state


def frame_seconds(exp, variables, repeats):
  """([seconds per frame], (height, width)): renders of test view 0's pose, from pose to pixels,
  through the training camera scaled to about RENDER_PIXELS pixels (Experiment.camera: same
  field of view and aspect), after one warm-up render that compiles."""
  scale = math.sqrt(RENDER_PIXELS / (exp.train_ds.height * exp.train_ds.width))
  camera = exp.camera(scale)
  draw = image_renderer.make_image_renderer(exp.renderer, exp.image)(variables)
  bg = background.parse(exp.config.data.background)
  pose = exp.test_ds.poses[0]
  return measure.sample_seconds(lambda: draw(exp.rays(pose, camera), bg), repeats), camera[:2]


def train_and_measure(config, options):
  """Train `config` under its budget in this process and measure it. Returns the record; its
  'machine' is the machine and its load while training (machine.Sampler's record)."""
  start = time.perf_counter()
  exp = experiment.setup(config)
  tc = config.train
  max_steps = builders.schedule_steps(tc)
  fitted = tc.max_seconds > 0 and options.fit_schedule
  # auto's step rule as training decides it (train_lib.step_rule_before_fit, fit_then_decide)
  exp, waiting = train_lib.step_rule_before_fit(exp, fitted)
  data = builders.make_train_data(exp)
  key = jax.random.PRNGKey(config.seed + 1)  # as train_lib.train_and_evaluate
  if fitted:
    # The schedule spans the steps expected to fit in the budget (the benchmark's clock counts
    # the compile, not the calibration); the clock alone ends the run.
    left = lambda compile_seconds: tc.max_seconds - compile_seconds

    def fit(run):  # `run`'s schedule fitted, on its own data (the decided run's built)
      nonlocal data
      if run is not exp:
        data = builders.make_train_data(run)
      return train_lib.fit_to_time(run, builders.make_train_step(run), data, key, left)

    exp, config, _ = train_lib.fit_then_decide(exp, waiting, fit, left)
    tc = config.train
    tx = optimizer.make_optimizer(builders.optimizer_settings(config))
    exp = dataclasses.replace(exp, config=config, tx=tx)
    max_steps = sys.maxsize
  jitted, state = _build(exp)
  evaluate = builders.make_evaluator(exp)
  clock = measure.Clock()

  def probe(state):
    psnr = evaluate(state.variables, max_views=options.eval_views)["psnr"]
    print(f"  {clock.seconds():7.1f} s  step {int(state.step):6d}  probe PSNR {psnr:.2f}",
          flush=True)
    return psnr

  probes = [{"seconds": 0.0, "step": 0, "psnr": probe(state)}]
  setup = {"setup_seconds": time.perf_counter() - start, "setup_rss_mb": measure.peak_rss_mb()}
  # The peak under the same machine load as this run's training, moments before it.
  peak = max(measure.matmul_gflops(config.model.dtype, repeats=options.matmul_repeats).values())
  sampler = machine.Sampler()  # the machine's load while it trains
  clock.start()
  compiled, compile_seconds = measure.compile_jitted(jitted, state, data, key)
  state, steps, segments, more, last_stats = train_loop(
      lambda s: compiled(s, data, key), state, max_steps, tc.max_seconds, options.eval_times,
      probe, clock)
  train_seconds = clock.stop()
  measured = sampler.stop()
  probes += more
  if probes[-1]["step"] != steps:
    probes.append({"seconds": train_seconds, "step": steps, "psnr": probe(state)})

  start = time.perf_counter()
  final = evaluate(state.variables, out_dir=options.eval_dir or None)
  eval_seconds = time.perf_counter() - start
  render_times, render_size = frame_seconds(exp, state.variables, options.render_repeats)
  step_seconds = measure.median_step_seconds(segments)
  rays = builders.rays_per_step(config, exp.train_ds)
  flops = measure.mlp_flops_per_step(state.params, config, rays)
  bad = int(state.bad_step)
  return {
      "test_psnr": final["psnr"], "test_ssim": final["ssim"], "test_lpips": final.get("lpips"),
      **{f"test_{name}": final[name] for name in evaluation.GEOMETRY_SCORES
         if name in final},
      "test_views": len(exp.test_ds),
      "psnr_at": {f"{t:g}": v for t, v in zip(options.eval_times,
                                              measure.psnr_at_times(probes, options.eval_times))},
      "probes": probes, "last_step_stats": last_stats, "steps": steps,
      "train_seconds": train_seconds,
      "compile_seconds": compile_seconds, "step_ms": 1e3 * step_seconds,
      "step_ms_samples": len(segments), "rays_per_step": rays,
      "rays_per_second": rays / step_seconds, "mlp_flops_per_step": flops,
      "mlp_gflops": flops / step_seconds / 1e9, "matmul_peak_gflops": peak,
      "peak_fraction": flops / step_seconds / 1e9 / peak,
      "render_ms": 1e3 * float(np.median(render_times)),
      "render_ms_samples": [1e3 * t for t in render_times], "render_size": list(render_size),
      "params": int(sum(x.size for x in jax.tree_util.tree_leaves(state.params))),
      "peak_rss_mb": measure.peak_rss_mb(), "device_peak_mb": measure.device_peak_mb(),
      "eval_seconds": eval_seconds, "diverged_at_step": bad + 1 if bad >= 0 else None,
      "schedule_steps": builders.schedule_steps(tc), "config": json.loads(config.to_json()),
      "machine": measured, **setup}


def worker(spec_path):
  """The subprocess of one run: run the config in `spec_path`, write its record (or its error).
  Returns the exit status."""
  with open(spec_path) as f:
    spec = json.load(f)
  try:
    record = train_and_measure(sweeps.as_config(spec["config"]), Options(**spec["options"]))
  except Exception as e:  # any failure of one run is reported in its record, the sweep goes on
    traceback.print_exc()
    record = {"error": f"{type(e).__name__}: {e}"}
  with open(spec["record_path"], "w") as f:
    json.dump(record, f)
  return 1 if "error" in record else 0


if __name__ == "__main__":
  sys.exit(worker(sys.argv[1]))
