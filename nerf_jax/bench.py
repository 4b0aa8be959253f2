"""What accuracy costs in time: train sweeps of configurations under equal budgets, measure them.

  python -m nerf_jax.bench --quick --out=bench_out/quick
  python -m nerf_jax.bench --sweep=samples,width --budget_seconds=300
  python -m nerf_jax.bench --sweep=effects --steps=500 --scenes=glossy,fog
  python -m nerf_jax.bench --sweep=freqs --scenes=data/lego --image_size=64

Each configuration runs in a fresh subprocess (clean peak RSS, no shared compile cache) that
trains it, measures it (the machine's matmul peak too, just before training, under the same
load) and hands back one record; the parent writes results.jsonl, then results.md and plots
(bench_plots.py) into --out. The sweeps are data in bench_sweeps.py. docs/benchmark.md explains
every number. Time words used below:
  train seconds: wall clock from the start of compiling the train step to the end of the last
    step, with the clock paused during PSNR probes; compile time is inside it.
  probe: PSNR on `eval_views` test views, taken at the last host sync before each probe time.
"""

import argparse
import contextlib
import dataclasses
import json
import os
import platform
import resource
import shlex
import subprocess
import sys
import tempfile
import time
import traceback

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax import (bench_plots, bench_sweeps, metrics, progress, render_lib, renderer,
                      scenes, train_lib)
from nerf_jax.data import loaders
from nerf_jax.model import make_model

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEGMENT_SECONDS = 0.25  # steps between host syncs: about this long (bounds budget overshoot)
MAX_SEGMENT_STEPS = 64
CALIBRATION_SECONDS = 3.0  # budget mode: time a throwaway run this long to fit the schedule
MATMUL_SHAPES = ((4096, 256, 256), (16384, 64, 64), (1024, 1024, 1024))  # (M, K, N)
RENDER_SIZE = 100  # render time is reported per RENDER_SIZE x RENDER_SIZE frame


@dataclasses.dataclass
class Options:
  """How each run is measured (the config says what is trained and for how long)."""
  eval_times: tuple = (15, 30, 60, 120, 300, 600)  # train seconds at which to probe PSNR
  eval_views: int = 1  # test views per probe (the final metrics use all)
  render_repeats: int = 5  # timed renders of a frame, after one warm-up
  matmul_repeats: int = 10  # timed matmuls per shape for the machine's peak
  fit_schedule: bool = True  # budget mode: stretch the lr schedule to the steps that fit


# ---------------------------------------------------------------- measuring


class Clock:
  """Training seconds: runs from start(), stands still while `paused()`."""

  def __init__(self):
    self._total, self._since = 0.0, None

  def start(self):
    self._since = time.perf_counter()

  def seconds(self):
    running = 0.0 if self._since is None else time.perf_counter() - self._since
    return self._total + running

  def stop(self):
    self._total, self._since = self.seconds(), None
    return self._total

  @contextlib.contextmanager
  def paused(self):
    self.stop()
    try:
      yield
    finally:
      self.start()


def compile_jitted(jitted, *args):
  """(executable, seconds to trace, lower and compile `jitted` for `args`); runs nothing."""
  start = time.perf_counter()
  compiled = jitted.lower(*args).compile()
  return compiled, time.perf_counter() - start


def sample_seconds(fn, repeats, warmup=1):
  """Wall seconds of `repeats` calls of `fn` (which must block) after `warmup` untimed calls."""
  for _ in range(warmup):
    fn()
  times = []
  for _ in range(repeats):
    start = time.perf_counter()
    fn()
    times.append(time.perf_counter() - start)
  return times


def matmul_gflops(dtype="float32", shapes=MATMUL_SHAPES, repeats=10):
  """This machine's dense matmul throughput: {'MxKxN': GFLOP/s}, median of `repeats`."""
  key_a, key_b = jax.random.split(jax.random.PRNGKey(0))
  result = {}
  for m, k, n in shapes:
    a = jax.random.normal(key_a, (m, k)).astype(dtype)
    b = jax.random.normal(key_b, (k, n)).astype(dtype)
    matmul, _ = compile_jitted(jax.jit(jnp.matmul), a, b)
    times = sample_seconds(lambda: matmul(a, b).block_until_ready(), repeats)
    result[f"{m}x{k}x{n}"] = 2.0 * m * k * n / float(np.median(times)) / 1e9
  return result


def mlp_flops_per_sample(net_params):
  """Forward FLOPs of one MLP evaluation: 2·in·out per Dense kernel [in, out] (biases ignored)."""
  leaves = jax.tree_util.tree_flatten_with_path(net_params)[0]
  return sum(2 * x.shape[0] * x.shape[1] for path, x in leaves
             if getattr(path[-1], "key", None) == "kernel")


def mlp_flops_per_step(params, config, rays_per_step):
  """MLP FLOPs of one train step: forward + backward ≈ 3 × forward, over every sample."""
  flops = mlp_flops_per_sample(params["coarse"]) * config.num_samples
  if config.num_fine_samples > 0:
    fine = params["coarse" if config.model.shared_fine else "fine"]
    flops += mlp_flops_per_sample(fine) * (config.num_samples + config.num_fine_samples)
  return 3 * rays_per_step * flops


def rays_per_step(config, dataset):
  """Rays in one train step: a batch of random rays, or whole images."""
  tc = config.train
  if tc.batching == "images":
    return tc.images_per_step * dataset.height * dataset.width
  return tc.batch_rays


def peak_rss_mb():
  """Peak resident memory of this process so far, in MiB."""
  peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
  return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes on macOS, KiB else


def device_peak_mb():
  """Peak accelerator memory in MiB where the backend reports it (not on CPU), else None."""
  stats = jax.devices()[0].memory_stats() or {}
  peak = stats.get("peak_bytes_in_use")
  return None if peak is None else peak / 2**20


def machine_info():
  """The machine and software versions the numbers belong to."""
  import flax
  import jaxlib
  import optax
  cpu = platform.processor()
  if os.path.exists("/proc/cpuinfo"):
    with open("/proc/cpuinfo") as f:
      names = [l.split(":", 1)[1].strip() for l in f if l.startswith("model name")]
    cpu = names[0] if names else cpu
  return {"cpu_model": cpu, "cpu_count": os.cpu_count(), "platform": platform.platform(),
          "backend": jax.default_backend(), "device_kind": jax.devices()[0].device_kind,
          "device_count": jax.device_count(), "python": platform.python_version(),
          "jax": jax.__version__, "jaxlib": jaxlib.__version__, "flax": flax.__version__,
          "optax": optax.__version__, "load_average": [round(x, 2) for x in os.getloadavg()]}


def psnr_at_times(probes, times):
  """PSNR reached by each time: that of the latest probe at or before it (None before any).

  probes: [{'seconds': float, 'psnr': float, ...}] in any order. times: [float] train seconds.
  """
  ordered = sorted(probes, key=lambda p: p["seconds"])
  out = []
  for t in times:
    before = [p["psnr"] for p in ordered if p["seconds"] <= t]
    out.append(before[-1] if before else None)
  return out


def median_step_seconds(segments):
  """Median over segments of seconds per step. segments: [(steps, seconds)]."""
  return float(np.median([seconds / steps for steps, seconds in segments]))


# ---------------------------------------------------------------- training one configuration


def train_loop(step_fn, state, max_steps, max_seconds, probe_times, probe, clock):
  """Step until `max_steps`, or until `clock` passes `max_seconds` (> 0); probe on the way.

  step_fn: state -> state, may return before the work is done; the loop syncs once per segment
  of steps (about SEGMENT_SECONDS long) and times the segment. probe: state -> PSNR, run with
  the clock paused at the last sync expected before each of `probe_times` (train seconds).
  Returns (state, steps, segments [(steps, seconds)], probes [{'seconds', 'step', 'psnr'}]).
  """
  pending = sorted(probe_times)
  segments, probes, step, size = [], [], 0, 1
  while step < max_steps and not (max_seconds > 0 and clock.seconds() >= max_seconds):
    size = min(size, max_steps - step)
    start = time.perf_counter()
    for _ in range(size):
      state = step_fn(state)
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
        probes.append({"seconds": now, "step": step, "psnr": float(probe(state))})
  return state, step, segments, probes


def _build(model, config, near, far):
  """(jitted train step, fresh TrainState) for `config`."""
  tx = train_lib.make_optimizer(config.train)
  # One compiled init instead of dozens of eagerly compiled small ops: same values, less setup.
  state = jax.jit(lambda: train_lib.init_state(model, tx, config))()
  return train_lib.make_train_step(model, tx, config, near, far), state


def calibrate(jitted, state, data, key):
  """(seconds per step, compile seconds) of a throwaway run of CALIBRATION_SECONDS, timed in
  segments as the real run is; the first step is left out."""
  compiled, compile_seconds = compile_jitted(jitted, state, data, key)
  clock = Clock()
  clock.start()
  _, _, segments, _ = train_loop(lambda s: compiled(s, data, key)[0], state, sys.maxsize,
                                 CALIBRATION_SECONDS, [], None, clock)
  return median_step_seconds(segments[1:] or segments), compile_seconds


class Viewer:
  """Renders a model's views with one compiled chunk renderer: test metrics and render timing."""

  def __init__(self, model, config, near, far, test_ds):
    self.config, self.test_ds = config, test_ds
    self.image_renderer = renderer.make_image_renderer(model, config, near, far)
    self.bound = (None, None)  # (params, their draw function): the skip grid once per params
    self.background = render_lib.background_colour(config)
    self.truths = render_lib.images_on_background(test_ds, config)[1]

  def render(self, params, pose, height, width, intrinsics):
    """numpy rgb float32 [height, width, 3] (and depth, acc) of one camera."""
    if self.bound[0] is not params:
      self.bound = (params, self.image_renderer(params))
    return render_lib.render_pose(self.bound[1], pose, height, width, intrinsics,
                                  self.config, self.background)

  def metrics(self, params, views=None, ssim=True):
    """Mean test PSNR (and SSIM, else None) over the first `views` test views (None = all)."""
    ds = self.test_ds
    psnrs, ssims = [], []
    for i in range(len(ds) if views is None else min(views, len(ds))):
      rgb = self.render(params, ds.poses[i], ds.height, ds.width, ds.intrinsics)["rgb"]
      psnrs.append(float(metrics.psnr(rgb, self.truths[i])))
      if ssim:
        ssims.append(float(metrics.ssim(rgb, self.truths[i])))
    return float(np.mean(psnrs)), (float(np.mean(ssims)) if ssim else None)

  def frame_seconds(self, params, repeats):
    """Seconds per RENDER_SIZE² frame of test view 0 (intrinsics rescaled), after a warm-up."""
    ds = self.test_ds
    fx, fy, cx, cy = ds.intrinsics
    sx, sy = RENDER_SIZE / ds.width, RENDER_SIZE / ds.height
    intrinsics = (fx * sx, fy * sy, cx * sx, cy * sy)
    return sample_seconds(lambda: self.render(params, ds.poses[0], RENDER_SIZE, RENDER_SIZE,
                                              intrinsics), repeats)


def run_config(config, options):
  """Train `config` under its budget in this process and measure it. Returns the record."""
  start = time.perf_counter()
  train_ds, test_ds = loaders.load_dataset(config.data)
  near, far = train_lib.bounds(config, train_ds)
  model = make_model(config.model)
  data = train_lib.make_train_data(train_ds, config)
  key = jax.random.PRNGKey(config.seed + 1)  # as train_lib.train_and_evaluate
  tc = config.train
  max_steps = tc.max_steps
  if tc.max_seconds > 0 and options.fit_schedule:
    # The schedule spans the steps expected to fit in the budget; the clock alone ends the run.
    step_seconds, compile_seconds = calibrate(*_build(model, config, near, far), data, key)
    fitted = (tc.max_seconds - compile_seconds) / step_seconds
    bench_sweeps.fit_schedule(tc, max(1, int(fitted)))
    max_steps = sys.maxsize
  jitted, state = _build(model, config, near, far)
  viewer = Viewer(model, config, near, far, test_ds)
  clock = Clock()

  def probe(state):
    psnr = viewer.metrics(state.params, options.eval_views, ssim=False)[0]
    print(f"  {clock.seconds():7.1f} s  step {int(state.step):6d}  probe PSNR {psnr:.2f}",
          flush=True)
    return psnr

  probes = [{"seconds": 0.0, "step": 0, "psnr": probe(state)}]
  setup = {"setup_seconds": time.perf_counter() - start, "setup_rss_mb": peak_rss_mb()}
  # The peak under the same machine load as this run's training, moments before it.
  peak = max(matmul_gflops(config.model.dtype, repeats=options.matmul_repeats).values())
  clock.start()
  compiled, compile_seconds = compile_jitted(jitted, state, data, key)
  state, steps, segments, more = train_loop(lambda s: compiled(s, data, key)[0], state,
                                            max_steps, tc.max_seconds, options.eval_times,
                                            probe, clock)
  train_seconds = clock.stop()
  probes += more
  if probes[-1]["step"] != steps:
    probes.append({"seconds": train_seconds, "step": steps, "psnr": probe(state)})

  start = time.perf_counter()
  test_psnr, test_ssim = viewer.metrics(state.params)
  eval_seconds = time.perf_counter() - start
  render_times = viewer.frame_seconds(state.params, options.render_repeats)
  step_seconds = median_step_seconds(segments)
  rays = rays_per_step(config, train_ds)
  flops = mlp_flops_per_step(state.params, config, rays)
  bad = int(state.bad_step)
  return {
      "test_psnr": test_psnr, "test_ssim": test_ssim, "test_views": len(test_ds),
      "psnr_at": {f"{t:g}": v for t, v in zip(options.eval_times,
                                              psnr_at_times(probes, options.eval_times))},
      "probes": probes, "steps": steps, "train_seconds": train_seconds,
      "compile_seconds": compile_seconds, "step_ms": 1e3 * step_seconds,
      "step_ms_samples": len(segments), "rays_per_step": rays,
      "rays_per_second": rays / step_seconds, "mlp_flops_per_step": flops,
      "mlp_gflops": flops / step_seconds / 1e9, "matmul_peak_gflops": peak,
      "peak_fraction": flops / step_seconds / 1e9 / peak,
      "render_ms": 1e3 * float(np.median(render_times)),
      "render_ms_samples": [1e3 * t for t in render_times],
      "params": int(sum(x.size for name, net in state.params.items() if name != "occupancy"
                        for x in jax.tree_util.tree_leaves(net))),  # trained weights only
      "peak_rss_mb": peak_rss_mb(), "device_peak_mb": device_peak_mb(),
      "eval_seconds": eval_seconds, "diverged_at_step": bad + 1 if bad >= 0 else None,
      "schedule_steps": tc.max_steps, "config": json.loads(config.to_json()), **setup}


# ---------------------------------------------------------------- running a sweep


def _worker(spec_path):
  """Subprocess entry: run the config in `spec_path` and write its record (or its error)."""
  with open(spec_path) as f:
    spec = json.load(f)
  try:
    record = run_config(bench_sweeps.as_config(spec["config"]), Options(**spec["options"]))
  except Exception as e:  # any failure of one run is reported in its record, the sweep goes on
    traceback.print_exc()
    record = {"error": f"{type(e).__name__}: {e}"}
  with open(spec["record_path"], "w") as f:
    json.dump(record, f)
  return 1 if "error" in record else 0


def run_isolated(config, options):
  """`run_config` in a fresh Python process; the record, or {'error': ...} if it died."""
  with tempfile.TemporaryDirectory() as tmp:
    spec_path, record_path = os.path.join(tmp, "spec.json"), os.path.join(tmp, "record.json")
    with open(spec_path, "w") as f:
      json.dump({"config": config.to_json(), "options": dataclasses.asdict(options),
                 "record_path": record_path}, f)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        p for p in (ROOT, os.environ.get("PYTHONPATH")) if p)}
    proc = subprocess.run([sys.executable, "-m", "nerf_jax.bench", "--worker", spec_path],
                          env=env, check=False)
    if not os.path.exists(record_path):
      return {"error": f"worker exited with status {proc.returncode} without a record"}
    with open(record_path) as f:
      return json.load(f)


def run_sweep(args, argv):
  """Run every planned configuration, writing results into args.out as they come."""
  runs = bench_sweeps.plan(args)
  each = f"{args.steps} steps" if args.steps else f"{args.budget_seconds:g} s of training"
  print(f"{len(runs)} runs of {each} each, into {args.out}:", flush=True)
  for sweep, entry, scene, _ in runs:
    print(f"  {sweep}/{entry.label} on {scene}", flush=True)
  if args.dry_run:
    return []
  os.makedirs(args.out, exist_ok=True)
  machine = machine_info()
  dtypes = sorted({"float32"} | {c.model.dtype for *_, c in runs})
  machine["matmul_gflops"] = {d: matmul_gflops(d, repeats=args.matmul_repeats) for d in dtypes}
  command = "python -m nerf_jax.bench " + " ".join(shlex.quote(a) for a in argv)
  options = Options(tuple(_floats(args.eval_times)), args.eval_views, args.render_repeats,
                    args.matmul_repeats, not args.keep_schedule)
  run = run_config if args.in_process else run_isolated
  open(os.path.join(args.out, "results.jsonl"), "w").close()
  records = []
  bar = progress.Progress(len(runs), "sweep")  # ETA from the runs done so far
  bar.update(0)  # the rate counts from now: every run, the first too, is a full run
  for i, (sweep, entry, scene, config) in enumerate(runs):
    bar.write(f"[{i + 1}/{len(runs)}] {sweep}/{entry.label} on {scene}")
    record = run(config, options)
    record.update(sweep=sweep, label=entry.label, base=entry.base, overrides=entry.overrides,
                  scene=bench_sweeps.scene_label(scene), mode=bench_sweeps.mode(args),
                  machine=machine, command=command, eval_times=list(options.eval_times))
    records.append(record)
    with open(os.path.join(args.out, "results.jsonl"), "a") as f:
      f.write(json.dumps(record) + "\n")
    bench_plots.write_report(records, args.out)
    bar.write(_summary(record))
    bar.update(i + 1, force=True)
  bar.close()
  return records


def _summary(record):
  if "error" in record:
    return f"  failed: {record['error']}"
  return (f"  test PSNR {record['test_psnr']:.2f} dB, SSIM {record['test_ssim']:.3f}, "
          f"{record['steps']} steps in {record['train_seconds']:.1f} s "
          f"(compile {record['compile_seconds']:.1f} s), step {record['step_ms']:.1f} ms, "
          f"render {record['render_ms']:.0f} ms/frame")


def _floats(text):
  return [float(x) for x in text.split(",") if x.strip()]


# ---------------------------------------------------------------- command line


def parse_args(argv):
  p = argparse.ArgumentParser(
      prog="python -m nerf_jax.bench",
      description="Train sweeps of NeRF configurations under equal budgets and measure quality, "
                  "speed and memory. See docs/benchmark.md.")
  p.add_argument("--sweep", default="all",
                 help=f"comma list of sweeps ({', '.join(bench_sweeps.SWEEPS)}) or 'all' "
                      "(every sweep but quick and default_tuning); default: all")
  p.add_argument("--quick", action="store_true",
                 help="the small sweep: --sweep=quick, 60 s per run on the diffuse scene")
  p.add_argument("--only", default="", help="comma list of configuration labels to keep")
  p.add_argument("--scenes", default="",
                 help=f"comma list of built-in scenes ({', '.join(scenes.SCENES)}) or dataset "
                      "paths (.npz, Blender or LLFF folder); default: each sweep's own")
  p.add_argument("--budget_seconds", type=float, default=None,
                 help="wall-clock training budget per run, compilation included "
                      "(default 120; 60 with --quick)")
  p.add_argument("--steps", type=int, default=0,
                 help="equal-step mode: train exactly this many steps instead of a budget")
  p.add_argument("--keep_schedule", action="store_true",
                 help="budget mode: keep the config's max_steps and lr schedule (as train.py "
                      "with train.max_seconds) instead of fitting them to the budget")
  p.add_argument("--eval_times", default="15,30,60,120,300,600",
                 help="train seconds at which to probe test PSNR (comma list)")
  p.add_argument("--eval_views", type=int, default=1,
                 help="test views per probe; the final metrics use all test views")
  p.add_argument("--image_size", type=int, default=None,
                 help="built-in scenes: image side in pixels (default: the config's, 100)")
  p.add_argument("--base", default="",
                 help="config replacing configs/default.py as the sweeps' base (name or path)")
  p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                 help="override a config field in every run, e.g. --set=train.batch_rays=2048")
  p.add_argument("--seed", type=int, default=None, help="config.seed of every run")
  p.add_argument("--render_repeats", type=int, default=5, help="timed renders per run")
  p.add_argument("--matmul_repeats", type=int, default=10, help="timed matmuls per shape")
  p.add_argument("--out", default="", help="output folder (default: bench_out/<sweeps>)")
  p.add_argument("--in_process", action="store_true",
                 help="run configurations in this process (peak RSS then accumulates)")
  p.add_argument("--dry_run", action="store_true", help="list the runs and exit")
  p.add_argument("--worker", help=argparse.SUPPRESS)
  args = p.parse_args(argv)
  if args.quick:
    args.sweep = "quick"
  if args.budget_seconds is None:
    args.budget_seconds = 60.0 if args.sweep == "quick" else 120.0
  args.out = args.out or os.path.join("bench_out", args.sweep.replace(",", "_"))
  return args


def main(argv=None):
  argv = sys.argv[1:] if argv is None else list(argv)
  args = parse_args(argv)
  if args.worker:
    return _worker(args.worker)
  try:
    run_sweep(args, argv)
  except ValueError as e:
    print(f"error: {e}", file=sys.stderr)
    return 1
  return 0


if __name__ == "__main__":
  sys.exit(main())
