"""The sweep's command line, `python -m nerf_jax.bench` (its flags and what it runs); the
commands run as command_line.py says, beside those of render.py and profile.py.

  python -m nerf_jax.bench --quick                                  # sweep_main
  python -m nerf_jax.bench --sweep=samples --config=mlp64 --config.train.batch_rays=2048
"""

import os
import shlex
import sys

from absl import flags

from nerf_jax.bench import command_line, report, runner, sweeps, timed_run


def _fail(message):
  print(f"error: {message}", file=sys.stderr)
  sys.exit(1)


def define_sweep_flags(values, argv):
  """The flags of `python -m nerf_jax.bench` on the FlagValues `values`. argv: the command line
  after cli.resolve_config_argv, where the config flag finds its --config.FIELD overrides."""
  command_line.define_config(values, argv, "Base config of the sweeps' entries based on "
                             "configs/default.py (a path or a name under configs/); "
                             "--config.FIELD=VALUE overrides apply to every run.")
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
  command_line.run_command(define_sweep_flags, sweep, argv, with_config=True)
