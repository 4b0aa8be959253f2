"""Train-step time of a sweep's configurations, side by side in one process.

  python -m nerf_jax.bench.step_time --sweep=detail --image_size=400 --steps=10

Every configuration is compiled first; then the steps are timed in rounds, one step of each
configuration per round, so a change of the machine's load hits all alike: the ratios hold on a
busy machine, the absolute milliseconds only on an idle one. Reports the median milliseconds per
step (compilation excluded), the ratio to the first configuration, and the steps that would fit
in --seconds at that median. Quality per step comes from the benchmark's equal-steps mode
(`python -m nerf_jax.bench --steps=N`); together they give quality at equal time.
"""

import time

import jax
import numpy as np
from absl import app, flags

from nerf_jax import cli
from nerf_jax.backend import errors
from nerf_jax.run import builders, experiment
from nerf_jax.run.signature import init_state
from nerf_jax.bench import sweeps


def num_params(params):
  return sum(int(np.prod(x.shape)) for x in jax.tree_util.tree_leaves(params))


def step_times(named_configs, steps, num_views=None):
  """{name: (median ms, params)} of each config's train step, timed in interleaved rounds.
  num_views: built-in scenes: views to render (None: the config's)."""
  runs = {}
  for name, config in named_configs:
    if num_views:
      config.data.num_views = num_views
    exp = experiment.setup(config)
    state = init_state(exp)
    data = builders.make_train_data(exp)
    step = builders.make_train_step(exp)
    key = jax.random.PRNGKey(0)
    state, _ = jax.block_until_ready(step(state, data, key))  # compile + one warm-up step
    runs[name] = [step, state, data, key, [], num_params(state.params)]
  for _ in range(steps):
    for run in runs.values():
      step, state, data, key, times, _ = run
      start = time.perf_counter()
      run[1], _ = jax.block_until_ready(step(state, data, key))
      times.append(time.perf_counter() - start)
  return {name: (1e3 * float(np.median(run[4])), run[5]) for name, run in runs.items()}


def print_table(results, seconds):
  """The results of `step_times` as a table, ratios to the first row."""
  first_ms = next(iter(results.values()))[0]
  print(f"{'configuration':<28} {'params':>11} {'ms/step':>9} {'x first':>8} "
        f"{'steps in ' + format(seconds, 'g') + ' s':>14}")
  for name, (ms, params) in results.items():
    print(f"{name:<28} {params:>11,} {ms:>9.1f} {ms / first_ms:>8.2f} {seconds * 1e3 / ms:>14.0f}")


def main(argv=None):
  sweep = flags.DEFINE_string("sweep", "detail", "the sweep whose configurations to time")
  only = flags.DEFINE_list("only", [], "configuration labels to keep")
  scenes = flags.DEFINE_list("scenes", [], "built-in scenes (default: the sweep's own)")
  image_size = flags.DEFINE_integer("image_size", None, "built-in scenes: image side")
  steps = flags.DEFINE_integer("steps", 10, "timed steps per configuration")
  seconds = flags.DEFINE_float("seconds", 600, "the budget whose step count to show")

  def run(_):
    request = sweeps.Request(sweep=sweep.value, only=tuple(only.value),
                             scenes=tuple(scenes.value), image_size=image_size.value, steps=1)
    named = [(f"{scene}/{entry.label}", config)
             for _, entry, scene, config in sweeps.plan(request)]
    print_table(step_times(named, steps.value), seconds.value)

  app.run(lambda argv: cli.run_main(lambda: run(argv)), argv=argv, flags_parser=errors.parse_flags)


if __name__ == "__main__":
  main()
