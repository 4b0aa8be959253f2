"""The benchmark's command lines, with train.py's conventions: absl flags, one --config flag
(a path or a name under configs/) with typed --config.FIELD=VALUE overrides, and errors the user
can fix printed as one line with exit status 1 (nerf_jax.cli).

  python -m nerf_jax.bench --quick                                  # sweep_main
  python -m nerf_jax.bench --sweep=samples --config=mlp64 --config.train.batch_rays=2048
  python -m nerf_jax.bench.render --workdir=runs/fast_diffuse       # render_speed_main
  python -m nerf_jax.bench.profile --config=fast                    # profile_main

Each command is `define_*_flags(flag_values, argv)` and a function of the parsed flag values, so
tests parse and run it on a private FlagValues; `*_main` runs it under absl's app.run.
"""

import json
import os
import shlex
import sys

import jax
import numpy as np
from absl import app, flags
from ml_collections import config_flags

from nerf_jax import cli
from nerf_jax.backend import errors
from nerf_jax.run import config_lib
from nerf_jax.bench import profile, render, report, runner, sweeps, timed_run


def _define_config(values, argv, help_text):
  config_flags.DEFINE_config_file("config", config_lib.resolve("default"), help_text,
                                  flag_values=values, lock_config=True, sys_argv=argv)


def _fail(message):
  print(f"error: {message}", file=sys.stderr)
  sys.exit(1)


def _main(define, command, argv, with_config):
  """Parse `argv` (default sys.argv) into the global flags defined by `define` and run
  command(flags.FLAGS, config spec, argv as given) under cli.run_main; exit status 0."""
  given = list(sys.argv if argv is None else argv)
  argv, spec = cli.resolve_config_argv(given) if with_config else (given, "")
  before = set(flags.FLAGS)
  define(flags.FLAGS, argv)
  for name in sorted(set(flags.FLAGS) - before):  # --help lists them as the command's own flags
    flags.FLAGS.register_key_flag_for_module(sys.argv[0], flags.FLAGS[name])

  def run(_):
    cli.run_main(lambda: command(flags.FLAGS, spec, given))  # app.run exits with what run returns

  app.run(run, argv=argv, flags_parser=errors.parse_flags)


# ---------------------------------------------------------------- python -m nerf_jax.bench


def define_sweep_flags(values, argv):
  """The flags of `python -m nerf_jax.bench` on the FlagValues `values`. argv: the command line
  after cli.resolve_config_argv, where the config flag finds its --config.FIELD overrides."""
  _define_config(values, argv, "Base config of the sweeps' entries based on configs/default.py "
                 "(a path or a name under configs/); --config.FIELD=VALUE overrides apply to "
                 "every run.")
  names = ", ".join(sweeps.SWEEPS)
  flags.DEFINE_string("sweep", "all", f"Comma list of sweeps ({names}) or 'all' (every sweep "
                      "but quick, default_tuning, detail and the frontiers).", flag_values=values)
  flags.DEFINE_bool("quick", False, "The small sweep: --sweep=quick, 60 s per run on the "
                    "diffuse scene.", flag_values=values)
  flags.DEFINE_list("only", [], "Configuration labels to keep.", flag_values=values)
  flags.DEFINE_list("scenes", [], "Built-in scenes or dataset paths (.npz, Blender or LLFF "
                    "folder); default: each sweep's own.", flag_values=values)
  flags.DEFINE_float("budget_seconds", None, "Wall-clock training budget per run, compilation "
                     "included (default 120; 60 with --quick).", flag_values=values)
  flags.DEFINE_integer("steps", 0, "Equal-step mode: train exactly this many steps instead of "
                       "a budget.", flag_values=values, lower_bound=0)
  flags.DEFINE_bool("keep_schedule", False, "Budget mode: keep the config's max_steps and lr "
                    "schedule (as train.py with train.max_seconds) instead of fitting them to "
                    "the budget.", flag_values=values)
  flags.DEFINE_list("eval_times", ["15", "30", "60", "120", "300", "600"], "Train seconds at "
                    "which to probe test PSNR.", flag_values=values)
  flags.DEFINE_integer("eval_views", 1, "Test views per probe; the final metrics use all test "
                       "views.", flag_values=values, lower_bound=1)
  flags.DEFINE_integer("image_size", None, "Built-in scenes: image side in pixels (default: the "
                       "config's).", flag_values=values, lower_bound=1)
  flags.DEFINE_integer("render_repeats", 5, "Timed renders per run.", flag_values=values,
                       lower_bound=1)
  flags.DEFINE_integer("matmul_repeats", 10, "Timed matmuls per shape.", flag_values=values,
                       lower_bound=1)
  flags.DEFINE_string("out", "", "Output folder (default: bench_out/<sweeps>).",
                      flag_values=values)
  flags.DEFINE_bool("in_process", False, "Run the configurations in this process (peak RSS "
                    "then accumulates).", flag_values=values)
  flags.DEFINE_bool("dry_run", False, "List the runs and exit.", flag_values=values)


def sweep_request(values, spec):
  """(sweeps.Request, timed_run.Options, output folder) of parsed sweep flags; spec: --config."""
  sweep = "quick" if values.quick else values.sweep
  budget = values.budget_seconds
  if budget is None:
    budget = 60.0 if sweep == "quick" else 120.0
  try:
    eval_times = tuple(float(t) for t in values.eval_times)
  except ValueError:
    raise ValueError(f"--eval_times={','.join(values.eval_times)}: expected a comma list of "
                     "seconds") from None
  request = sweeps.Request(
      sweep=sweep, only=tuple(values.only), scenes=tuple(values.scenes), base=spec,
      overrides=dict(values["config"].override_values), image_size=values.image_size,
      steps=values.steps, budget_seconds=budget, keep_schedule=values.keep_schedule)
  options = timed_run.Options(eval_times, values.eval_views, values.render_repeats,
                              values.matmul_repeats, not values.keep_schedule)
  return request, options, values.out or os.path.join("bench_out", sweep.replace(",", "_"))


def sweep(values, spec, argv):
  """Run the sweep the parsed flags ask for; argv: the command line as given (for the report)."""
  problem = None if values.dry_run else report.missing_dependency()
  if problem:  # at start-up, not after the first run has trained
    _fail(problem)
  request, options, out = sweep_request(values, spec)
  command = "python -m nerf_jax.bench " + shlex.join(argv[1:])
  return runner.run_sweep(request, options, out, command, values.in_process, values.dry_run)


def sweep_main(argv=None):
  """`python -m nerf_jax.bench`."""
  _main(define_sweep_flags, sweep, argv, with_config=True)


# ---------------------------------------------------------------- python -m nerf_jax.bench.render


def define_render_flags(values, argv=None):
  """The flags of `python -m nerf_jax.bench.render` on the FlagValues `values`."""
  del argv  # no config flag: the workdir's saved config is the config
  flags.DEFINE_string("workdir", None, "A training run with a checkpoint.", flag_values=values,
                      required=True)
  flags.DEFINE_integer("frame_size", 100, "Longer side of the timed frame, pixels.",
                       flag_values=values, lower_bound=1)
  flags.DEFINE_integer("repeats", 10, "Timed frame renders.", flag_values=values, lower_bound=1)
  flags.DEFINE_integer("frames", 120, "Frames of the timed video.", flag_values=values,
                       lower_bound=1)
  flags.DEFINE_list("sizes", ["800"], "Big-frame sides whose peak RSS to measure.",
                    flag_values=values)
  flags.DEFINE_string("out", "", "JSON output (default <workdir>/bench_render.json).",
                      flag_values=values)
  flags.DEFINE_integer("worker_size", 0, "Internal: render one frame of this side in this "
                       "process and print its RSS record.", flag_values=values)


def render_speed(values, spec="", argv=None):
  """Measure the parsed flags' workdir, write the record and print its lines."""
  del spec, argv
  if not os.path.isdir(values.workdir):
    raise FileNotFoundError(f"--workdir={values.workdir}: no such directory")
  if values.worker_size:
    print(json.dumps(render.big_frame_rss(values.workdir, values.worker_size)))
    return None
  try:
    sizes = [int(s) for s in values.sizes]
  except ValueError:
    raise ValueError(f"--sizes={','.join(values.sizes)}: expected a comma list of "
                     "pixels") from None
  record = render.measure_workdir(values.workdir, values.frame_size, values.repeats,
                                  values.frames, sizes)
  out = values.out or os.path.join(values.workdir, "bench_render.json")
  with open(out, "w") as f:
    json.dump(record, f, indent=2)
  print("\n".join(render.summary_lines(record, values.repeats) + [f"-> {out}"]))
  return record


def render_speed_main(argv=None):
  """`python -m nerf_jax.bench.render`."""
  _main(define_render_flags, render_speed, argv, with_config=False)


# ---------------------------------------------------------------- python -m nerf_jax.bench.profile


def define_profile_flags(values, argv):
  """The flags of `python -m nerf_jax.bench.profile` on the FlagValues `values`."""
  _define_config(values, argv, "The config whose train step to profile (a path or a name under "
                 "configs/), with --config.FIELD=VALUE overrides.")
  flags.DEFINE_integer("repeats", 10, "Timed calls per stage.", flag_values=values,
                       lower_bound=1)
  flags.DEFINE_integer("ops", 0, "Also list this many of the step's costliest kinds of XLA "
                       "operation, from a profiler trace (0 = no trace).", flag_values=values,
                       lower_bound=0)
  flags.DEFINE_integer("warm_steps", 0, "Train this many steps before timing, so that an "
                       "occupancy grid has found the empty space (0 = time the first state).",
                       flag_values=values, lower_bound=0)


def profile_table(values, spec, argv=None):
  """Print the stage table of the parsed flags' config."""
  del argv
  print(f"{spec}: {jax.devices()[0].device_kind}, jax {jax.__version__}")
  print("| stage | median ms | note |\n|---|---|---|")
  rows = profile.profile(values.config, values.repeats, values.warm_steps)
  for stage, ms, note in rows:
    print(f"| {stage} | {'' if np.isnan(ms) else f'{ms:.1f}'} | {note} |")
  if values.ops:
    kinds = profile.op_kinds(values.config, values.repeats, values.warm_steps)
    print("\n| XLA operation kind | ms per step (all threads) |\n|---|---|")
    for kind, ms in kinds[:values.ops]:
      print(f"| {kind} | {ms:.2f} |")
    print(f"| all | {sum(ms for _, ms in kinds):.1f} |")
  return rows


def profile_main(argv=None):
  """`python -m nerf_jax.bench.profile`."""
  _main(define_profile_flags, profile_table, argv, with_config=True)
