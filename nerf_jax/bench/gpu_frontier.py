"""The GPU session's one script (issue 40): the configs/gpu/ configs trained and scored on lego,
fox and fern, the profile of one GPU step, and the scatter-add check; one table.

  python -m nerf_jax.bench.gpu_frontier --lego=DIR --fox=DIR --fern=DIR --out=$OUT
  python -m nerf_jax.bench.gpu_frontier --lego=DIR --seconds=lego=300 --out=$OUT   # lego alone
  python -m nerf_jax.bench.gpu_frontier --lego=DIR --fields=lego:model.hash.gather_dtype=bfloat16
  python -m nerf_jax.bench.gpu_frontier --smoke --out=/tmp/smoke   # the CPU, tiny, no folders

Each stage runs in its own process under its own time limit, within --total seconds (default
510, for a 9-minute session with the install before it):
  1. each scene given (a folder; --smoke: a built-in scene of its kind, shrunk to seconds):
     configs/gpu/lego.py (white background), gpu/capture.py (fox as shipped, data.factor=4),
     gpu/llff.py (fern, data.factor=8), trained for --seconds under the benchmark's clock
     (bench/timed_run.py: compile included, probes excluded) with PSNR probed at 15, 30, 60, 120
     and 300 s where the run lasts that long (a probe inside a longer run, whose learning rate
     still decays towards the run's end: not the run of that length), then scored on every
     test view; a scene trains for less when the time left is short (its row says how long);
  2. `python -m nerf_jax.bench.profile` on gpu/lego's step (on the lego folder if given, else
     the built-in diffuse scene), after --warm_steps steps, with the costliest XLA operations;
  3. `python -m nerf_jax.bench.scatter_add` at gpu/lego's table and sample budget.
Writes to --out: frontier.md (the tables, the issue's goals met or short, how each scene's
sample budget was used at its last step, each stage's output)
and frontier.json (every record: steps, probes, scores, step and compile times, device memory),
both rewritten after each stage, a log per stage, and scatter.json.
"""

import ast
import json
import os
import sys
import tempfile
import time

from absl import app, flags

from nerf_jax.bench import child, records

# The scenes: (config, overrides on a folder, the built-in scene of its kind for --smoke).
SCENES = {"lego": ("gpu/lego", {"data.background": "white"}, "diffuse"),
          "fox": ("gpu/capture", {"data.factor": 4}, "garden"),
          "fern": ("gpu/llff", {"data.factor": 8}, "forward")}
SECONDS = {"lego": 60.0, "fox": 60.0, "fern": 120.0}  # training seconds: the issue's goals'
# The issue's goals (one H100 or H200, compile included): scene -> [(seconds, test PSNR dB)].
GOALS = {"lego": [(60.0, 35.0), (300.0, 36.0)], "fox": [(60.0, 28.5)], "fern": [(120.0, 25.5)]}
PROBE_SECONDS = (15.0, 30.0, 60.0, 120.0, 300.0)
SCENE_OVERHEAD_S = 150  # a scene's limit beyond its training: setup, calibration, scoring
MIN_OVERHEAD_S = 60  # with less time left than seconds + this, a scene trains for less
STAGE_LIMIT_S = {"profile": 100, "scatter-add check": 50}  # the checks' time limits
SMOKE_LIMIT_S = 600  # --smoke: each stage's limit on a CPU, in place of --total's
# --smoke: each config shrunk to seconds on a CPU (a tiny field, image and step count).
SMOKE_FIELDS = {"data.path": "", "data.num_views": 6, "data.image_size": 16,
                "data.holdout_from": 5, "train.max_steps": 3, "train.max_seconds": 0.0,
                "train.batch_rays": 128, "train.log_every": 3, "train.checkpoint_every": 3,
                "train.tensorboard": False, "render.video_frames": 0,
                "render.after_training": False}
SMOKE_MODEL = {"gpu/lego": {"model.hash.levels": 4, "model.hash.log2_size": 10,
                            "model.hash.max_resolution": 64, "occupancy.resolution": 16,
                            "num_samples": 8, "train.sample_budget": 512,
                            "render.num_samples": 0},
               "gpu/llff": {"model.grid.resolutions": (8, 16), "num_samples": 16}}
SMOKE_MODEL["gpu/capture"] = SMOKE_MODEL["gpu/lego"]
DEVICE = ("import jax; d = jax.devices()[0]; "
          "print(jax.default_backend(), '|', getattr(d, 'device_kind', d.platform), '|', "
          "'jax', jax.__version__)")

def define_flags(values):
  """The command's flags on the FlagValues `values` (defined when it runs, not at import: other
  bench modules name flags alike)."""
  flags.DEFINE_string("lego", "", "A Blender folder of lego (empty: skipped, unless --smoke).",
                      flag_values=values)
  flags.DEFINE_string("fox", "", "instant-ngp's fox folder as shipped (empty: skipped).",
                      flag_values=values)
  flags.DEFINE_string("fern", "", "LLFF's fern folder (empty: skipped).", flag_values=values)
  flags.DEFINE_list("scenes", list(SCENES), "The scenes to run (of those given a folder).",
                    flag_values=values)
  flags.DEFINE_list("seconds", [], "Training seconds per scene as scene=seconds, e.g. "
                    "lego=120,fern=60 (default lego=60, fox=60, fern=120).", flag_values=values)
  flags.DEFINE_list("fields", [], "Config fields for one scene as scene:field=value, e.g. "
                    "lego:data.half_res=True,lego:model.hash.gather_dtype=bfloat16.",
                    flag_values=values)
  flags.DEFINE_integer("total", 510, "Seconds for every stage together.", flag_values=values)
  flags.DEFINE_integer("eval_views", 2, "Test views per probe (the final score uses all).",
                       flag_values=values)
  flags.DEFINE_integer("warm_steps", 100, "Profile: train steps before timing (the occupancy "
                       "grid filled in).", flag_values=values)
  flags.DEFINE_string("out", "/tmp/gpu_frontier", "Folder for frontier.md, frontier.json, "
                      "the logs.", flag_values=values)
  flags.DEFINE_bool("smoke", False, "Built-in scenes and tiny fields: the whole script on a "
                    "CPU in minutes (its numbers mean nothing; each stage's limit "
                    f"{SMOKE_LIMIT_S} s).", flag_values=values)

def _env():
  """The children's environment: this checkout first on the path, no GPU preallocation (the
  stages run one after the other, but the parent's children share the device with nothing)."""
  return child.env(preallocate=False)


def device():
  """'backend | device kind | jax version' of the first jax device, from a child process (this
  one never starts a backend: it would hold device memory while the stages run)."""
  return child.python_line(DEVICE, _env())


def parse_seconds(items):
  """{scene: seconds} of SECONDS updated by ['scene=seconds', ...]; ValueError naming a bad one."""
  seconds = dict(SECONDS)
  for item in items:
    scene, _, value = item.partition("=")
    if scene not in SCENES or not value:
      raise ValueError(f"--seconds={item}: expected scene=seconds with a scene of "
                       f"{', '.join(SCENES)}")
    seconds[scene] = float(value)
  return seconds


def parse_fields(items):
  """{scene: {dotted field: value}} of ['scene:field=value', ...]: each value a Python literal
  where it parses as one ('True', '0.5', '(8,16)'), else the string; ValueError naming a bad
  item."""
  fields = {}
  for item in items:
    scene, _, assignment = item.partition(":")
    field, _, text = assignment.partition("=")
    if scene not in SCENES or not field or not text:
      raise ValueError(f"--fields={item}: expected scene:field=value with a scene of "
                       f"{', '.join(SCENES)}")
    try:
      value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
      value = text
    fields.setdefault(scene, {})[field] = value
  return fields


def scene_config(scene, folder, seconds, smoke):
  """(config name, {dotted field: value}) of one scene's run: its GPU config on `folder` for
  `seconds` of training; with `smoke`, on the built-in scene of its kind, shrunk."""
  name, overrides, builtin = SCENES[scene]
  if smoke:
    return name, {**SMOKE_FIELDS, "data.scene": builtin, **SMOKE_MODEL[name]}
  return name, {"data.path": folder, **overrides, "train.max_seconds": seconds,
                "render.video_frames": 0, "render.after_training": False}


def timed_record(name, overrides, probe_times, eval_views, log, timeout):
  """The record of bench/timed_run.py for config `name` with `overrides`, run in a child
  process (its output into `log`); {'error': ...} when it fails or runs out of time."""
  with tempfile.TemporaryDirectory() as tmp:
    spec, record = os.path.join(tmp, "spec.json"), os.path.join(tmp, "record.json")
    with open(spec, "w") as f:
      json.dump({"config": _config_json(name, overrides), "record_path": record,
                 "options": {"eval_times": list(probe_times), "eval_views": eval_views,
                             "render_repeats": 3, "matmul_repeats": 3}}, f)
    code, seconds = child.run_logged([sys.executable, "-m", "nerf_jax.bench.timed_run", spec],
                                     log, timeout, _env())
    if not os.path.exists(record):
      return {"error": f"exit {code} after {seconds:.0f} s without a record (log: {log})"}
    with open(record) as f:
      return json.load(f)


def _config_json(name, overrides):
  """configs/<name>.py with `overrides` (dotted fields) set, as JSON."""
  from nerf_jax.run import config_lib  # pylint: disable=import-outside-toplevel  (no jax start)
  config = config_lib.load(name)
  for field, value in overrides.items():
    config_lib.set_field(config, field, value)
  return config.to_json()


def goal_lines(scene, record, seconds):
  """One line per goal of the issue for `scene`: met, short by how much, or not run so long.
  A goal at the run's length is read from the final score (all test views), an earlier one
  from the probe before it (--eval_views views, inside the longer run)."""
  lines = []
  for at, target in GOALS[scene]:
    if at > seconds:
      lines.append(f"≥ {target} dB at {at:g} s: not measured (the run lasted {seconds:g} s)")
      continue
    final = at == seconds
    psnr = record["test_psnr"] if final else record["psnr_at"].get(f"{at:g}")
    if psnr is None:
      lines.append(f"≥ {target} dB at {at:g} s: no probe by then")
      continue
    verdict = "met" if psnr >= target else f"short by {target - psnr:.2f} dB"
    where = "all test views" if final else "probe views, within the longer run"
    lines.append(f"≥ {target} dB at {at:g} s: {psnr:.2f} dB ({where}): {verdict}")
  return lines


def budget_line(record):
  """How the sample budget was used at the run's last step (None without a budget): the rays
  it held whole of those drawn, and the valid samples they asked for against it. Far above
  the budget, most drawn rays are sampled in vain; below it, budget slots go empty (either
  way a ray count adapted to the budget, as nerfacc's, would do better)."""
  stats, train = record.get("last_step_stats", {}), record.get("config", {}).get("train", {})
  if "colour/samples_wanted" not in stats or not train.get("sample_budget"):
    return None
  wanted, budget = stats["colour/samples_wanted"], train["sample_budget"]
  return (f"the last step's budget: {stats['colour/rays_in_loss']:,} of {train['batch_rays']:,} drawn "
          f"rays in the loss; they asked for {wanted:,} samples, {wanted / budget:.2f}× the "
          f"budget of {budget:,}")


def scene_table(results, machine):
  """The scenes' rows as a markdown table (results: {scene: (config, seconds, record)})."""
  head = " | ".join(f"@{t:g}s" for t in PROBE_SECONDS)
  lines = [f"device: {machine}", "",
           f"| scene | config | s | steps | ms/step | {head} | test PSNR | SSIM | "
           "render ms (100 px) | status |",
           "|---|---|---:|---:|---:|" + "---:|" * len(PROBE_SECONDS) + "---:|---:|---:|---|"]
  for scene, (name, seconds, r) in results.items():
    if "error" in r:
      lines.append(f"| {scene} | {name} | {seconds:g} | | | {' | ' * len(PROBE_SECONDS)}"
                   f" | | | {r['error']} |")
      continue
    probes = " | ".join(_num(r["psnr_at"].get(f"{t:g}")) if t <= seconds else ""
                        for t in PROBE_SECONDS)
    lines.append(f"| {scene} | {name} | {seconds:g} | {r['steps']:,} | {r['step_ms']:.2f} | "
                 f"{probes} | {r['test_psnr']:.2f} | {r['test_ssim']:.3f} | "
                 f"{r['render_ms']:.0f} | ok |")
  lines.append("")
  for scene, (_, seconds, r) in results.items():
    if "error" not in r:
      lines += [f"- {scene}: {line}" for line in goal_lines(scene, r, seconds)]
      used = budget_line(r)
      lines += [f"- {scene}: {used}"] if used else []
  return lines


def _num(value):
  return "" if value is None else f"{value:.2f}"


def profile_args(smoke, lego, warm_steps):
  """The command line of the profile stage: gpu/lego's step on the `lego` folder (else on the
  built-in diffuse scene: a step's cost is set by its sample budget, not by the images); with
  `smoke`, shrunk as the scenes are."""
  if smoke:
    fields = {"data.scene": "diffuse", "data.num_views": 6, "data.image_size": 16,
              "train.batch_rays": 128, **SMOKE_MODEL["gpu/lego"]}
  else:
    fields = {"data.path": lego, "data.background": "white"} if lego else {}
  return [sys.executable, "-m", "nerf_jax.bench.profile", "--config=gpu/lego",
          *(f"--config.{k}={v}" for k, v in fields.items()),
          f"--warm_steps={2 if smoke else warm_steps}", f"--repeats={2 if smoke else 10}",
          f"--ops={3 if smoke else 15}"]


def write_report(out, machine, results, stages):
  """frontier.md and frontier.json in `out` (stages: {name: {'status', 'text'}})."""
  lines = [f"# GPU frontier, {time.strftime('%Y-%m-%d %H:%M')}", "", "command: python -m "
           "nerf_jax.bench.gpu_frontier " + " ".join(sys.argv[1:]), "",
           *scene_table(results, machine)]
  for name, stage in stages.items():
    lines += ["", f"## {name} ({stage['status']})", "", stage["text"].rstrip()]
  with open(os.path.join(out, "frontier.md"), "w") as f:
    f.write("\n".join(lines) + "\n")
  report = {"device": machine, "argv": sys.argv[1:], "stages": stages,
            "scenes": {s: {"config": c, "seconds": t, "record": r}
                       for s, (c, t, r) in results.items()}}
  with open(os.path.join(out, "frontier.json"), "w") as f:
    json.dump(records.stamp(report, measured=_children_machine(results)), f, indent=1)


def _children_machine(results):
  """The machine record a scene's run measured (its child process), or a bare one naming the
  device: the parent never starts JAX, which would take the GPU's memory from its children."""
  for _, _, record in results.values():
    if isinstance(record, dict) and isinstance(record.get("machine"), dict):
      return record["machine"]
  return {"device": "not measured: no scene's run finished"}


def _stage_text(log, keep):
  """The last `keep` lines of a stage's log (its table, or its error)."""
  with open(log) as f:
    return "".join(f.readlines()[-keep:])


def run(values):
  """Every stage the parsed flags `values` ask for, within values.total seconds; the report is
  rewritten after each (`write_report`) and printed at the end."""
  os.makedirs(values.out, exist_ok=True)
  end = time.perf_counter() + values.total  # --smoke: not enforced (SMOKE_LIMIT_S per stage)
  left = lambda: end - time.perf_counter()
  machine = device()
  print(f"gpu_frontier on {machine}; into {values.out}", flush=True)
  results, stages = {}, {}
  for scene in SCENES:
    if scene in values.scenes and (getattr(values, scene) or values.smoke):
      results[scene] = run_scene(values, scene, left)
      write_report(values.out, machine, results, stages)
      print("\n".join(scene_table({scene: results[scene]}, machine)[2:]), flush=True)
  for i, (name, args, keep) in enumerate(checks(values)):
    log = os.path.join(values.out, f"{name.split()[0]}.log")
    later = sum(list(STAGE_LIMIT_S.values())[i + 1:])  # the checks after this one
    limit = SMOKE_LIMIT_S if values.smoke else min(STAGE_LIMIT_S[name], left() - later)
    code, spent = child.run_logged(args, log, limit, _env())
    stages[name] = {"status": f"exit {code}, {spent:.0f} s", "text": _stage_text(log, keep)}
    write_report(values.out, machine, results, stages)
  print(open(os.path.join(values.out, "frontier.md")).read(), flush=True)


def run_scene(values, scene, left):
  """(config name, training seconds, record) of one scene under the flags `values`, its
  training shrunk to what left() leaves after the checks and MIN_OVERHEAD_S."""
  folder, smoke = getattr(values, scene), values.smoke
  wanted = parse_seconds(values.seconds)[scene]
  limit = (SMOKE_LIMIT_S if smoke else
           min(wanted + SCENE_OVERHEAD_S, left() - sum(STAGE_LIMIT_S.values())))
  seconds = 0.0 if smoke else min(wanted, limit - MIN_OVERHEAD_S)
  name, overrides = scene_config(scene, folder, seconds, smoke)
  overrides.update(parse_fields(values.fields).get(scene, {}))
  if seconds < 15 and not smoke:
    return name, seconds, {"error": f"skipped: {left():.0f} s left"}
  print(f"== {scene}: {name}, {seconds:g} s (limit {limit:.0f} s)", flush=True)
  probes = [t for t in PROBE_SECONDS if t <= seconds] or [1.0]
  log = os.path.join(values.out, f"{scene}.log")
  return name, seconds, timed_record(name, overrides, probes, values.eval_views, log, limit)


def checks(values):
  """[(stage name, command line, log lines kept)] of the checks after the scenes: the profile
  of gpu/lego's step and the scatter-add check at its table."""
  scatter = [sys.executable, "-m", "nerf_jax.bench.scatter_add", "--config=gpu/lego",
             f"--out={os.path.join(values.out, 'scatter.json')}"]
  scatter += ["--smoke", "--repeats=2"] if values.smoke else []
  return [("profile", profile_args(values.smoke, values.lego, values.warm_steps), 40),
          ("scatter-add check", scatter, 12)]


def main(argv=None):
  """`python -m nerf_jax.bench.gpu_frontier`."""
  define_flags(flags.FLAGS)
  app.run(lambda _: run(flags.FLAGS), argv=argv)


if __name__ == "__main__":
  main()
