"""Where a train step's time goes: each stage of the step timed alone, side by side.

  python -m nerf_jax.bench.profile                          # configs/default.py
  python -m nerf_jax.bench.profile --config=fast --config.train.batch_rays=2048
  python -m nerf_jax.bench.profile --config=detail --warm_steps=300   # occupancy grid filled in

Stages (each jitted on its own, median of --repeats calls after a warm-up): the library's whole
train step (train_step.make_train_step); drawing the batch; sampling + encoding (forward only:
nothing upstream needs a gradient); the field's forward + backward on pre-encoded inputs;
compositing forward + backward; and plain matmuls with the MLP's shapes, [rays·samples, in] ×
[in, out], forward only. The stages do not add up exactly (XLA fuses across them in the real
step), but they show which one dominates and how far the MLP (fwd + bwd ≈ 3 × the forward FLOPs)
is from the matmul speed of its own shapes and from the large-square matmul peak. The flags are
at the end of this module (define_profile_flags).

With --ops=N it also lists the N costliest kinds of XLA operation in the whole step (a profiler
trace of --repeats steps: fusions named by their root op, e.g. every gather fusion together),
which shows what the stages cannot: the zero-filled gradient tables, the scatters, the sorts.
"""

import collections
import glob
import gzip
import json
import os
import re
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np
from absl import flags

from nerf_jax.render import compositing
from nerf_jax.run import builders, experiment
from nerf_jax.run.signature import init_state
from nerf_jax.samplers import placement
from nerf_jax.train import train_batches
from nerf_jax.bench import command_line, measure


def median_ms(fn, *args, repeats=10):
  """Median wall milliseconds of fn(*args) (jitted, blocking), compilation excluded."""
  compiled = jax.jit(fn).lower(*args).compile()
  run = lambda: jax.block_until_ready(compiled(*args))
  return 1e3 * float(np.median(measure.sample_seconds(run, repeats)))


def _kernels(params):
  leaves = jax.tree_util.tree_flatten_with_path(params)[0]
  return [x for path, x in leaves if getattr(path[-1], "key", None) == "kernel"]


def _warmed(config, warm_steps):
  """(exp, state, data, key, step): `config`'s experiment and its state after `warm_steps`
  train steps (an occupancy grid then holds what the field has found, as in a real run)."""
  exp = experiment.setup(config)
  state = init_state(exp)
  data = builders.make_train_data(exp)
  key = jax.random.PRNGKey(0)
  step = builders.make_train_step(exp)
  for _ in range(warm_steps):
    state, _ = step(state, data, key)
  return exp, jax.block_until_ready(state), data, key, step


def profile(config, repeats=10, warm_steps=0):
  """[(stage, ms, note)] for one train step of `config` on its dataset, after `warm_steps`."""
  exp, state, data, key, step = _warmed(config, warm_steps)
  rays, samples = builders.rays_per_step(config, exp.train_ds), config.num_samples
  times = []
  for _ in range(repeats + 1):  # the first call compiles, unless the warm steps did: not counted
    start = time.perf_counter()
    state, stats = step(state, data, key)
    jax.block_until_ready((state, stats))  # the whole step done on the device
    times.append(time.perf_counter() - start)
  rows = [("train step (all)", 1e3 * float(np.median(times[1:])), f"{rays} rays × {samples}")]

  batch = train_batches.draw_batch(data, builders.batch_settings(config), key).rays
  rows.append(("draw batch (gathers)", median_ms(
      lambda k: train_batches.draw_batch(data, builders.batch_settings(config), k), key,
      repeats=repeats), ""))

  field = exp.renderer.field

  def sample(batch, k):
    placed = exp.renderer.sampler.place(batch, k, state.buffers.get("occupancy"))
    return field.network_points(placement.points(batch, placed.distances))
  features = sample(batch, key)  # the points: the network applies its encoding (in its row)
  rows.append(("sample (fwd)", median_ms(sample, batch, key, repeats=repeats),
               f"{features.shape}"))

  params = state.params["coarse"]
  dirs = None
  if config.model.view_dependent:
    dirs = jnp.zeros((*features.shape[:-1], field.dir_width))
  field_sum = lambda p, x: jnp.sum(sum(jnp.sum(o) for o in field.network.apply({"params": p}, x,
                                                                                 dirs)))
  rows.append(("field fwd+bwd", median_ms(jax.grad(field_sum), params, features,
                                          repeats=repeats),
               f"{len(_kernels(params))} dense layers"))

  rgb = jnp.full((rays, samples, 3), 0.5)
  sigma = jnp.ones((rays, samples))
  t = jnp.broadcast_to(jnp.linspace(exp.near, exp.far, samples + 1), (rays, samples + 1))
  composite = lambda c, s: jnp.sum(compositing.composite(c, s, t)["rgb"])
  rows.append(("composite fwd+bwd", median_ms(jax.grad(composite, argnums=(0, 1)), rgb, sigma,
                                               repeats=repeats), ""))

  n = rays * samples
  kernels = _kernels(params)
  inputs = [jnp.ones((n, k.shape[0])) for k in kernels]
  flops = sum(2 * n * k.shape[0] * k.shape[1] for k in kernels)
  ms = median_ms(lambda xs, ks: [x @ k for x, k in zip(xs, ks)], inputs, kernels,
                 repeats=repeats)
  rows.append(("the MLP's matmuls alone (fwd)", ms, f"{flops / ms / 1e6:.1f} GFLOP/s at its "
               "shapes"))
  field_ms = rows[3][1]
  rows[3] = (*rows[3][:2], f"{rows[3][2]}, {3 * flops / field_ms / 1e6:.1f} GFLOP/s")
  peak = max(measure.matmul_gflops(repeats=repeats).values())
  rows.append(("dense matmul peak", float("nan"), f"{peak:.1f} GFLOP/s (large square)"))
  return rows


# Trace events that hold other events (the executor, control flow, Python frames): not counted.
_CONTAINERS = ("ThunkExecutor", "PjitFunction", "$", "cond", "while", "call", "conditional")


def op_kinds(config, repeats=10, warm_steps=0):
  """[(kind, ms per step)] of the XLA operations of `config`'s train step, costliest first:
  a profiler trace of `repeats` steps after `warm_steps` and a warm-up, each operation's time
  summed by its name without the trailing number (copy_gather_fusion.3 -> copy_gather_fusion).
  On a CPU the operations of one step may run on several threads at once, so the sum can
  exceed the step."""
  _, state, data, key, step = _warmed(config, warm_steps)
  state, stats = step(state, data, key)
  jax.block_until_ready(stats)
  with tempfile.TemporaryDirectory() as folder:
    jax.profiler.start_trace(folder, create_perfetto_trace=True)
    for _ in range(repeats):
      state, stats = step(state, data, key)
      jax.block_until_ready(stats)
    jax.profiler.stop_trace()
    trace, = glob.glob(os.path.join(folder, "**", "*.trace.json.gz"), recursive=True)
    with gzip.open(trace) as f:
      events = json.load(f)
  events = events["traceEvents"] if isinstance(events, dict) else events
  totals = collections.Counter()
  for event in events:
    name = event.get("name", "")
    if event.get("ph") == "X" and not name.startswith(_CONTAINERS) and "::" not in name:
      totals[re.sub(r"[.\d]+$", "", name)] += event.get("dur", 0) / 1e3 / repeats
  return totals.most_common()


# ---------------------------------------------------------------- python -m nerf_jax.bench.profile


def define_profile_flags(values, argv):
  """The flags of `python -m nerf_jax.bench.profile` on the FlagValues `values`."""
  command_line.define_config(values, argv, "The config whose train step to profile (a path or "
                             "a name under configs/), with --config.FIELD=VALUE overrides.")
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
  rows = profile(values.config, values.repeats, values.warm_steps)
  for stage, ms, note in rows:
    print(f"| {stage} | {'' if np.isnan(ms) else f'{ms:.1f}'} | {note} |")
  if values.ops:
    kinds = op_kinds(values.config, values.repeats, values.warm_steps)
    print("\n| XLA operation kind | ms per step (all threads) |\n|---|---|")
    for kind, ms in kinds[:values.ops]:
      print(f"| {kind} | {ms:.2f} |")
    print(f"| all | {sum(ms for _, ms in kinds):.1f} |")
  return rows


def profile_main(argv=None):
  """`python -m nerf_jax.bench.profile`."""
  command_line.run_command(define_profile_flags, profile_table, argv, with_config=True)


if __name__ == "__main__":
  profile_main()
