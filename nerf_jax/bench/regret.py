"""Auto's regret: does `--config=auto` choose the best config at equal training time?

  python -m nerf_jax.bench.regret --scene=diffuse --seconds=60 --out=runs/regret
  python -m nerf_jax.bench.regret --scene=forward --seconds=60 --out=runs/regret --dry_run

Trains, each for the same wall-clock budget (train.max_seconds = --seconds), auto's config, auto's
config with each of its decisions flipped alone, and the other representations auto could have
chosen (regret_plan.py), each in a fresh process into OUT/<run>/ (train_lib.train_and_evaluate;
its metrics.json gives the scores, scored as the data calls for). Writes OUT/results.jsonl (one
record per run), OUT/table.md and OUT/regret_<scene>.png (each run's PSNR gain over auto against
its step-cost ratio; needs matplotlib, the [bench] extra). Auto's regret: the best run's score
minus auto's (0 when auto is best); the score is PSNR, its mean over the scales for multiscale
data. docs/regret.md explains every column.
"""

import hashlib
import json
import os
import shlex
import sys
import time

import jax
import ml_collections
from absl import flags

from nerf_jax import cli
from nerf_jax.bench import child, command_line, regret_plan, report, standard
from nerf_jax.bench import records as records_lib
from nerf_jax.data.scenes import builtin
from nerf_jax.run import config_lib, experiment, train_lib
from nerf_jax.run import machine as machine_lib

LOG_NAME = "log.txt"  # each run's output, in its workdir


def scene_config(config, scene, data_path, seconds, overrides=()):
  """(a copy of `config` that trains `scene` (a built-in scene name) or the data at
  `data_path` for `seconds`, {field: value} the command set: these and `overrides`, the
  dotted fields of the command line). The fields go into config.auto_flags: auto keeps them.
  One-line ValueError or FileNotFoundError for a bad scene name or a missing folder."""
  if data_path and not os.path.exists(data_path):
    raise FileNotFoundError(f"--data_path={data_path}: not found")
  if not data_path:
    builtin.get_scene(scene)  # ValueError naming the valid scenes
  fields = {**({"data.path": data_path} if data_path else {"data.scene": scene}),
            "train.max_seconds": float(seconds), "render.after_training": False}
  return command_line.command_config(config, fields, overrides)


def train_isolated(config, workdir):
  """train_lib.train_and_evaluate of `config` into `workdir` in a fresh Python process, its
  output in workdir/LOG_NAME. Returns the run's metrics.json (a dict), or {'error': line}."""
  os.makedirs(workdir, exist_ok=True)
  spec = os.path.join(workdir, "regret_config.json")
  with open(spec, "w") as f:
    f.write(config.to_json())
  code = ("import sys; from nerf_jax.bench import regret; "
          "sys.exit(regret.worker(sys.argv[1], sys.argv[2]))")
  status, _ = child.run_logged([sys.executable, "-c", code, spec, workdir],
                               os.path.join(workdir, LOG_NAME),
                               environment=child.env(preallocate=False))
  metrics = os.path.join(workdir, "metrics.json")
  if status or not os.path.exists(metrics):
    with open(os.path.join(workdir, LOG_NAME)) as f:
      lines = [l.strip() for l in f if l.strip()]
    return {"error": f"exit status {status}: {lines[-1] if lines else 'no output'}"}
  with open(metrics) as f:
    return json.load(f)


def worker(spec_path, workdir):
  """The process of one run: train the config saved at `spec_path` into `workdir`. Returns the
  exit status (1 with one line for an error the user can fix)."""
  with open(spec_path) as f:
    config = config_lib.upgrade(ml_collections.ConfigDict(json.load(f)))
  try:
    train_lib.train_and_evaluate(config, workdir)
  except cli.USER_ERRORS as e:
    print(f"{type(e).__name__}: {e}", flush=True)
    return 1
  return 0


def score(record):
  """The score a run is judged by: the mean PSNR over the scales where the data has scales
  (mip-NeRF's multiscale tables), else the PSNR; None for a failed run."""
  return record.get("mean_over_scales_psnr", record.get("psnr"))


def seconds_per_step(log, metrics):
  """A run's seconds per training step: between its first and last logged steps
  (metrics.jsonl records with 'loss', the compile before the first left out), else its
  train_seconds over its steps. log: [dict], metrics.jsonl's records; metrics: metrics.json."""
  logged = [r for r in log if "loss" in r and "wall_seconds" in r]
  if len(logged) >= 2 and logged[-1]["step"] > logged[0]["step"]:
    return ((logged[-1]["wall_seconds"] - logged[0]["wall_seconds"]) /
            (logged[-1]["step"] - logged[0]["step"]))
  return metrics["train_seconds"] / max(metrics["steps"], 1)


# What a run's saved config may differ in from auto's and still be auto's config: auto's record
# and the schedule its time budget fitted. A flip of an effect auto's step rule turned off at
# this budget trains auto's own config: its gain is the run-to-run noise, not a regret.
NOT_THE_CONFIG = ("auto_decisions", "auto_by_steps", "auto_flags", "auto_representation",
                  "train.max_steps", "train.warmup_steps")


def trained_config(workdir):
  """A short hash of the config a run trained (workdir/config.json) less NOT_THE_CONFIG;
  None where the run saved none."""
  path = os.path.join(workdir, "config.json")
  if not os.path.exists(path):
    return None
  with open(path) as f:
    config = json.load(f)
  for name in NOT_THE_CONFIG:
    *sections, field = name.split(".")
    node = config
    for section in sections:
      node = node.get(section, {})
    node.pop(field, None)
  return hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()[:16]


def make_record(run, metrics, scene, log=()):
  """One results.jsonl record of `run` (a regret_plan.Run) from its metrics.json `metrics`
  (or {'error': ...}) and metrics.jsonl `log` ([dict]), with metrics.json's 'machine' (measured
  while the run trained, run/machine.py) where it has one; the step-cost ratio and gain come
  later (`with_regret`), the stamp (records.py) in `run_plan`."""
  record = {"scene": scene, "run": run.name, "flipped": run.flipped, "base": run.base,
            "overrides": run.overrides,
            **({"machine": metrics["machine"]} if "machine" in metrics else {})}
  if "error" in metrics:
    return {**record, "error": metrics["error"]}
  record.update(psnr=metrics["psnr"], ssim=metrics.get("ssim"), lpips=metrics.get("lpips"),
                steps=metrics["steps"], seconds=metrics["train_seconds"])
  record["seconds_per_step"] = seconds_per_step(log, metrics)
  if "by_scale" in metrics:
    record["by_scale_psnr"] = {k: v["psnr"] for k, v in metrics["by_scale"].items()}
    record["mean_over_scales_psnr"] = metrics["mean_over_scales"]["psnr"]
  for key in ("masks", "appearance", "held_out_poses"):  # how the views were scored, if said
    if key in metrics:
      record[f"scored_{key}"] = metrics[key]
  return record


def with_regret(records):
  """`records` (dicts of one scene, auto's named 'auto') with each run's 'gain' (its score
  minus auto's) and 'step_cost_ratio' (its seconds per step over auto's), 'same_as_auto' on a
  run that trained auto's own config (the same 'trained' hash: `trained_config`), and the
  regret: max(0, best score - auto's score) over the other runs, None while auto's run has no
  score. Returns (records, regret)."""
  auto_run = next((r for r in records if r["run"] == "auto"), {})
  base = score(auto_run)
  out = []
  for record in records:
    record = dict(record)
    if record["run"] != "auto" and auto_run.get("trained"):
      record["same_as_auto"] = record.get("trained") == auto_run["trained"]
    if base is not None and score(record) is not None:
      record["gain"] = score(record) - base
      record["step_cost_ratio"] = record["seconds_per_step"] / auto_run["seconds_per_step"]
    out.append(record)
  return out, (None if base is None else max(0.0, max(score(r) for r in rivals(out)) - base))


def rivals(records):
  """The runs of `records` auto's regret is taken over: every scored run but those that trained
  auto's own config (with_regret's 'same_as_auto')."""
  return [r for r in records if score(r) is not None and not r.get("same_as_auto")]


def format_cell(value, form):
  """A table cell: `value` formatted with `form`, '-' for None."""
  return "-" if value is None else format(value, form)


def table(records, regret, command):
  """table.md of one scene's `records` (with_regret's) and its `regret`."""
  scene = records[0]["scene"] if records else "-"
  best = max(rivals(records), key=score, default={})
  lines = [f"# Auto's regret on {scene}", "", "```", command, "```", "",
           f"Auto's regret: {format_cell(regret, '.2f')} dB (best: {best.get('run', '-')}).", "",
           "| run | flipped | overrides | PSNR | mean over scales | gain | SSIM | LPIPS | steps "
           "| s/step | step-cost ratio | error |", "|---" * 12 + "|"]
  cell = format_cell
  for r in records:
    overrides = ", ".join(f"{k}={v!r}" for k, v in r["overrides"].items()) or "-"
    marks = (" (auto's config)" if r.get("same_as_auto") else "") + machine_lib.busy_note(
        r.get("machine"))
    lines.append(
        f"| {r['run']}{marks} | {r['flipped'] or '-'} | {overrides} | {cell(r.get('psnr'), '.2f')} | "
        f"{cell(r.get('mean_over_scales_psnr'), '.2f')} | {cell(r.get('gain'), '+.2f')} | "
        f"{cell(r.get('ssim'), '.3f')} | {cell(r.get('lpips'), '.3f')} | "
        f"{cell(r.get('steps'), 'd')} | {cell(r.get('seconds_per_step'), '.4f')} | "
        f"{cell(r.get('step_cost_ratio'), '.2f')} | {r.get('error', '')} |")
  return "\n".join(lines) + "\n"


def write_results(records, regret, out, command):
  """OUT/results.jsonl (one record a line, the regret on each) and OUT/table.md."""
  os.makedirs(out, exist_ok=True)
  records_lib.write(os.path.join(out, "results.jsonl"),
                    [{**record, "regret": regret} for record in records])
  with open(os.path.join(out, "table.md"), "w") as f:
    f.write(table(records, regret, command))


def picture(records, regret, path):
  """regret_<scene>.png at `path`: each scored run's gain over auto (dB) against its step-cost
  ratio. Returns None, or the line saying matplotlib is missing (nothing drawn)."""
  problem = report.missing_dependency()
  if problem:
    return problem
  from matplotlib import figure  # pylint: disable=import-outside-toplevel  (optional: [bench])
  fig = figure.Figure(figsize=(6.5, 4.5))
  axes = fig.subplots()
  scored = [r for r in records if r.get("gain") is not None]
  for r in scored:
    axes.scatter(r["step_cost_ratio"], r["gain"], color="C3" if r["run"] == "auto" else "C0")
    axes.annotate(r["run"], (r["step_cost_ratio"], r["gain"]), fontsize=7,
                  textcoords="offset points", xytext=(4, 3))
  axes.axhline(0.0, color="grey", linewidth=0.8)
  axes.axvline(1.0, color="grey", linewidth=0.8)
  axes.set_xlabel("step-cost ratio (seconds per step / auto's)")
  axes.set_ylabel("PSNR gain over auto (dB)")
  scene = records[0]["scene"] if records else ""
  axes.set_title(f"{scene}: auto's regret {format_cell(regret, '.2f')} dB")
  fig.tight_layout()
  fig.savefig(path, dpi=120)
  return None


def print_plan(runs, skipped, seconds, out):
  """The planned runs, one line each with its overrides, and the ones left out."""
  print(f"{len(runs)} runs of {seconds:g} s of training each, into {out}:", flush=True)
  for run in runs:
    shown = ("auto's config" if run.name == "auto" else
             " ".join(f"--config.{k}={v!r}" for k, v in run.overrides.items()))
    print(f"  {run.name} ({run.base}): {shown}", flush=True)
  for line in skipped:
    print(f"  {line}", flush=True)


def chosen(runs, names):
  """The Runs of `runs` named in `names` (all where `names` is empty), in the plan's order;
  ValueError with one line naming a run the plan does not hold. Names that all start with '-'
  leave those runs out of the plan instead (absent ones too: one list for every scene's plan,
  e.g. -config/hash); a list mixing both is refused."""
  if not names:
    return runs
  left_out = [n[1:] for n in names if n.startswith("-")]
  if left_out:
    if len(left_out) != len(names):
      raise ValueError(f"--runs={','.join(names)}: name the runs to train, or the runs to leave "
                       "out each with a leading '-', not both")
    return [r for r in runs if r.name not in left_out]
  unknown = sorted(set(names) - {r.name for r in runs})
  if unknown:
    raise ValueError(f"--runs: {unknown[0]} is not a planned run (planned: "
                     f"{', '.join(r.name for r in runs)})")
  return [r for r in runs if r.name in names]


def workdir_of(run, out):
  """OUT/<run name with '_' for '/'>: where `run` trains."""
  return os.path.join(out, run.name.replace("/", "_"))


def check_fresh(runs, out):
  """ValueError with one line where a run's workdir under `out` holds files already: a run
  would resume an earlier one's checkpoint, not train for the budget from the start."""
  used = [workdir_of(r, out) for r in runs
          if os.path.isdir(workdir_of(r, out)) and os.listdir(workdir_of(r, out))]
  if used:
    raise ValueError(f"{used[0]} holds an earlier run (a run would resume it): give a new "
                     "--out or remove it")


def run_plan(runs, scene, out, command):
  """Train every Run of `runs` (auto's first) into OUT/<run name>; records and results written
  after each. Returns (records, regret)."""
  check_fresh(runs, out)
  records = []
  for i, run in enumerate(runs):
    workdir = workdir_of(run, out)
    print(f"[{i + 1}/{len(runs)}] {run.name}: training into {workdir}", flush=True)
    start = time.perf_counter()
    metrics = train_isolated(run.config, workdir)
    record = make_record(run, metrics, scene, records_lib.read(
        os.path.join(workdir, "metrics.jsonl")) if "error" not in metrics else ())
    record.update(workdir=workdir, wall_seconds=round(time.perf_counter() - start, 1),
                  trained=trained_config(workdir))
    # The machine the run measured; a failed run's: what the machine is, not its load.
    record = records_lib.stamp(record)
    records.append(record)
    scored, regret = with_regret(records)
    write_results(scored, regret, out, command)
    print(f"  {record.get('error') or format(score(record), '.2f') + ' dB'}"
          f"{machine_lib.busy_note(record.get('machine'))}", flush=True)
  return scored, regret


# ------------------------------------------------------- python -m nerf_jax.bench.regret


def define_regret_flags(values, argv):
  """The flags of `python -m nerf_jax.bench.regret` on the FlagValues `values`."""
  command_line.define_config(values, argv, "The config auto starts from (default auto); "
                             "--config.FIELD=VALUE overrides apply to every run.")
  flags.DEFINE_string("scene", "diffuse", "A built-in scene (data.scene), or the name of the "
                      "data at --data_path in the records.", flag_values=values)
  flags.DEFINE_string("data_path", "", "A data folder (data.path) in place of a built-in "
                      "scene.", flag_values=values)
  flags.DEFINE_float("seconds", 60.0, "Wall-clock training budget of every run "
                     "(train.max_seconds).", flag_values=values, lower_bound=0.0)
  flags.DEFINE_string("out", "runs/regret", "Output folder: results.jsonl, table.md, the "
                      "picture and one workdir per run.", flag_values=values)
  flags.DEFINE_bool("dry_run", False, "Decide auto's config and list the runs; train nothing.",
                    flag_values=values)
  flags.DEFINE_list("runs", [], "Only these of the planned runs (e.g. auto,flip/cones): a "
                    "part of the table, or one run again; default every run. Names each with "
                    "a leading '-' (e.g. -config/hash) leave those out instead.",
                    flag_values=values)


def regret(values, spec, argv):
  """Run (or, with --dry_run, list) the runs the parsed flags ask for. Returns (records,
  regret); ([], None) for a dry run."""
  del spec
  config, user = scene_config(values["config"].value, values.scene, values.data_path,
                              values.seconds, cli.override_names(argv))
  if not config.auto:
    raise ValueError("regret measures auto's decisions: leave --config=auto")
  result, train_ds, _ = experiment.load_decided(config)
  runs, skipped = regret_plan.plan(result, user, train_ds.height, train_ds.width,
                                   jax.default_backend(), train_ds.image_cameras is None)
  runs = chosen(runs, values.runs)
  print_plan(runs, skipped, values.seconds, values.out)
  if values.dry_run:
    return [], None
  command = "python -m nerf_jax.bench.regret " + shlex.join(argv[1:])
  records, value = run_plan(runs, values.scene, values.out, command)
  path = os.path.join(values.out, f"regret_{values.scene}.png")
  problem = picture(records, value, path)
  print(f"auto's regret on {values.scene}: {format_cell(value, '.2f')} dB -> "
        f"{os.path.join(values.out, 'table.md')}" + (f"; no picture: {problem}" if problem
                                                       else f", {path}"), flush=True)
  return records, value


def regret_main(argv=None):
  """`python -m nerf_jax.bench.regret`."""
  given = list(sys.argv if argv is None else argv)
  # Every process takes the device memory it uses, not 75% of it at start: the command's own
  # process (which decided auto's config) holds some while each run trains in its own.
  os.environ.update(child.NO_PREALLOCATION)  # before JAX starts its backend
  command_line.run_command(define_regret_flags, regret, standard.normalised_argv(given),
                           with_config=True)


if __name__ == "__main__":
  regret_main()
