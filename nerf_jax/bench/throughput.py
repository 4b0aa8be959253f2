"""The throughput check: training steps a second of each shipped config on this machine, recorded,
and compared with the last records of the same config on the same kind of machine.

  python -m nerf_jax.bench.throughput                          # CONFIGS, 200 steps each
  python -m nerf_jax.bench.throughput --configs=fast,hash --steps=300 --check

Each config trains on its built-in scene (SCENES: the configs made for a data folder get the
built-in scene of their kind, as bench/fingerprint.py does) of --num_views views of
--image_size pixels a side, its lr schedule and batch as the config has them, no time budget:
the train step is compiled, --warmup steps run, then --steps steps are timed between two host
syncs while run/machine.py samples the machine's load. One JSON line per config goes to --out
(default docs/bench/throughput/<backend>.jsonl): the config's identity (IDENTITY: name, scene,
image size, rays per step), steps/s and rays/s, stamped (records.py: date, git, the machine
record of the timed steps).

Each config's printed line compares its rate with the baseline: the median rate of the last
three records (BASELINE_RUNS) of the same identity on the same kind of machine (KIND: CPU model,
CPU count, the CPUs the run may use, backend and device) whose machine was not busy: rate now,
rate before, their ratio, and the verdict
(`judge`): 'slower' where the rate fell by more than --tolerance (15%), 'faster' where it rose
by more, 'ok' between, 'first' with no earlier idle record, and 'busy' (not judged) where this
run's machine was busy. --check exits with status 1 when a config is 'slower'.
"""

import os
import shlex
import sys
import time

import jax
from absl import flags

from nerf_jax.bench import command_line, fingerprint, measure, records
from nerf_jax.run import builders, config_lib, experiment, machine, train_lib
from nerf_jax.run.signature import init_state

CONFIGS = ("default", "fast", "detail", "capture", "llff", "hash", "mipnerf")
SCENES = fingerprint.SCENES  # the built-in scene of a config made for a data folder
IDENTITY = ("config", "scene", "image_size", "rays_per_step")  # the same work a step
KIND = ("cpu_model", "cpu_count", "cpus_used", "backend", "device_kind")  # the same machine
TOLERANCE = 0.15  # a rate more than this fraction below the baseline is a slowdown
BASELINE_RUNS = 3  # the baseline: the median of this many last idle records of the same work


def throughput_config(name, image_size, num_views):
  """configs/<name>.py on its built-in scene of `num_views` views of `image_size` pixels a side,
  without a time budget (its max_steps or default_steps span the schedule)."""
  config = config_lib.load(name)
  fields = {"data.image_size": image_size, "data.num_views": num_views,
            "data.holdout_from": -1, "train.max_seconds": 0.0}
  if name in SCENES:
    fields.update({"data.path": "", "data.scene": SCENES[name]})
  for field, value in fields.items():
    config_lib.set_field(config, field, value)
  return config


def measure_config(name, config, steps, warmup):
  """Time `steps` train steps of `config` (named `name`) after compiling and `warmup` steps.
  Returns the record: IDENTITY's fields, 'batch_rays', 'num_views', 'warmup_steps', 'steps',
  'seconds', 'compile_seconds', machine.rates' fields and 'machine' (the load while timed)."""
  exp = experiment.setup(config)
  exp = train_lib.with_step_rule(exp, builders.schedule_steps(exp.config.train))
  data = builders.make_train_data(exp)
  key = jax.random.PRNGKey(config.seed + 1)  # as train_lib.train_and_evaluate
  state = jax.jit(lambda: init_state(exp))()
  step, compile_seconds = measure.compile_jitted(builders.make_train_step(exp), state, data, key)
  for _ in range(warmup):
    state, _ = step(state, data, key)
  jax.block_until_ready(state)
  sampler = machine.Sampler()
  start = time.perf_counter()
  for _ in range(steps):
    state, _ = step(state, data, key)
  jax.block_until_ready(state)
  seconds = time.perf_counter() - start
  measured = sampler.stop()
  rays = builders.rays_per_step(exp.config, exp.train_ds)
  return {"config": name, "scene": exp.config.data.scene, "image_size": config.data.image_size,
          "num_views": config.data.num_views, "batch_rays": exp.config.train.batch_rays,
          "rays_per_step": rays, "warmup_steps": warmup, "steps": steps,
          "seconds": round(seconds, 4), "compile_seconds": round(compile_seconds, 2),
          **machine.rates(steps, rays, seconds), "machine": measured}


def same_work(a, b):
  """Whether records `a` and `b` timed the same step (IDENTITY) on the same kind of machine
  (KIND)."""
  return (all(a.get(k) == b.get(k) for k in IDENTITY) and
          all(a["machine"].get(k) == b["machine"].get(k) for k in KIND))


def baseline(record, history):
  """The median by rate of the last BASELINE_RUNS records of `history` (oldest first) of the
  same work as `record` (`same_work`) whose machine was not busy (the upper of two), or None.
  A median, not the last record alone: one idle run of a small step (default.py's ~40 ms)
  varied 22-29 steps/s from run to run on one VM, the same with the code before and after."""
  earlier = [r for r in history if same_work(r, record) and not r["machine"].get("busy")]
  last = sorted(earlier[-BASELINE_RUNS:], key=lambda r: r["steps_per_second"])
  return last[len(last) // 2] if last else None


def judge(record, before, tolerance=TOLERANCE):
  """(ratio of steps/s now over before or None, verdict): 'first' without `before`, 'busy'
  where `record`'s machine was busy (not judged), 'slower' below 1 - tolerance, 'faster'
  above 1 + tolerance, else 'ok'."""
  if before is None:
    return None, "first"
  ratio = record["steps_per_second"] / before["steps_per_second"]
  if record["machine"].get("busy"):
    return ratio, "busy"
  if ratio < 1.0 - tolerance:
    return ratio, "slower"
  return ratio, "faster" if ratio > 1.0 + tolerance else "ok"


def line(record, before, ratio, verdict):
  """One printed line: the config, its rate now and before, the ratio, the verdict and whether
  the machine was busy."""
  now = (f"{record['config']}: {record['steps_per_second']:.2f} steps/s "
         f"({record['rays_per_second']:,.0f} rays/s) now")
  if before is None:
    then = "no earlier record on an idle machine of this kind"
  else:
    code = (before["machine"].get("git") or "unknown")[:12]  # the commit's short form
    then = (f"{before['steps_per_second']:.2f} before ({before.get('date', '?')}, code "
            f"{code}), ratio {ratio:.2f}")
  return f"{now}, {then}: {verdict}{machine.busy_note(record['machine'])}"


def check(names, out, steps, warmup, image_size, num_views, tolerance, command):
  """Measure each config of `names`, append its record to `out`, print its line. Returns the
  verdicts {name: verdict}."""
  history, verdicts = records.read(out), {}
  for name in names:
    print(f"{name}: compiling, {warmup} warm-up steps, {steps} timed steps", flush=True)
    record = measure_config(name, throughput_config(name, image_size, num_views), steps, warmup)
    record = records.stamp({**record, "command": command})  # its machine: measured while timed
    before = baseline(record, history)
    ratio, verdicts[name] = judge(record, before, tolerance)
    records.append(out, record)
    history.append(record)
    print(line(record, before, ratio, verdicts[name]), flush=True)
  return verdicts


# ------------------------------------------------------- python -m nerf_jax.bench.throughput


def define_throughput_flags(values, argv):
  """The flags of `python -m nerf_jax.bench.throughput` on the FlagValues `values`."""
  del argv
  flags.DEFINE_list("configs", list(CONFIGS), "Configs to time (names under configs/).",
                    flag_values=values)
  flags.DEFINE_integer("steps", 200, "Timed train steps per config.", flag_values=values,
                       lower_bound=1)
  flags.DEFINE_integer("warmup", 20, "Untimed steps after compiling, before the timed ones.",
                       flag_values=values, lower_bound=0)
  flags.DEFINE_integer("image_size", 64, "Pixels a side of the built-in scene's views.",
                       flag_values=values, lower_bound=8)
  flags.DEFINE_integer("num_views", 24, "Views of the built-in scene.", flag_values=values,
                       lower_bound=2)
  flags.DEFINE_float("tolerance", TOLERANCE, "A rate this fraction below the last one on the "
                     "same kind of machine is a slowdown.", flag_values=values, lower_bound=0.0)
  flags.DEFINE_string("out", "", "The JSON-lines file of records (default "
                      "docs/bench/throughput/<backend>.jsonl).", flag_values=values)
  flags.DEFINE_bool("check", False, "Exit with status 1 when a config is slower than before.",
                    flag_values=values)


def throughput(values, spec, argv):
  """Run the check the parsed flags ask for; exits with status 1 for a slowdown with --check.
  Returns the verdicts {config: verdict}."""
  del spec
  for name in values.configs:
    config_lib.resolve(name)  # a misspelt name fails before anything is timed
  out = values.out or os.path.join("docs", "bench", "throughput", f"{jax.default_backend()}.jsonl")
  command = "python -m nerf_jax.bench.throughput " + shlex.join(argv[1:])
  verdicts = check(values.configs, out, values.steps, values.warmup, values.image_size,
                   values.num_views, values.tolerance, command)
  slower = [name for name, verdict in verdicts.items() if verdict == "slower"]
  print(f"{len(verdicts)} configs -> {out}" + (f"; slower: {', '.join(slower)}" if slower
                                               else ""), flush=True)
  if values.check and slower:
    sys.exit(1)
  return verdicts


def throughput_main(argv=None):
  """`python -m nerf_jax.bench.throughput`."""
  given = list(sys.argv if argv is None else argv)
  command_line.run_command(define_throughput_flags, throughput, given, with_config=False)


if __name__ == "__main__":
  throughput_main()
