"""The regret table: auto's regret (bench/regret.py) on many scenes, run side by side on the
machine's cores, and one table of every scene's gains (docs/regret.md).

  python -m nerf_jax.bench.regret_table --seconds=60 --out=runs/regret_table
  python -m nerf_jax.bench.regret_table --scenes=crowd,glossy --workers=1 --out=runs/rt
  python -m nerf_jax.bench.regret_table --summarize --out=runs/regret_table

Each scene's `python -m nerf_jax.bench.regret` runs in its own process into OUT/<scene>/ (its
output in OUT/<scene>.log). `--workers` scenes run at once, worker i pinned to core i where the
machine has that many (os.sched_setaffinity): every run then trains on one core beside the
same kind of neighbour, so the runs of a scene stay comparable at equal time. The command's
--config.FIELD=VALUE overrides and --runs go to every scene's command.

Writes OUT/table.md and OUT/summary.jsonl from every OUT/*/results.jsonl (so scenes run apart,
e.g. real data at a longer budget into the same OUT, join the table): one row per scene with
auto's config and score, the best run, auto's regret, and each flip's and each other
representation's gain over auto; and OUT/regret_table.png, one panel per scene of each run's
gain against its step-cost ratio (matplotlib: the [bench] extra).
"""

import os
import sys
import threading

from absl import flags

from nerf_jax.bench import child, command_line, regret, regret_plan, report, standard
from nerf_jax.bench import records as records_lib

# The built-in scenes of the table (docs/regret.md), the slowest first: landmark's runs carve a
# hull and fit zooms before training; the collections fit held-out codes after it.
SCENES = ("landmark", "crowd", "garden", "exposure", "forward", "glossy", "multiscale",
          "diffuse", "fog", "white", "perturbed")
DEFAULT_RUNS = ("-config/hash",)  # 5x auto's step on a CPU; lost 4.5 dB at 120 s (regret.md)


def scene_command(scene, seconds, out, passed):
  """argv of one scene's regret command. passed: the table command's own arguments that go to
  every scene (--config overrides, --runs)."""
  return [sys.executable, "-m", "nerf_jax.bench.regret", f"--scene={scene}",
          f"--seconds={seconds:g}", f"--out={os.path.join(out, scene)}", *passed]


def passed_on(argv, runs):
  """The arguments of `argv` (the table command's) for every scene's command: --config and
  its --config.FIELD overrides, and --runs (`runs`, default DEFAULT_RUNS)."""
  own = [a for a in argv[1:] if a.startswith("--config")]
  return own + [f"--runs={','.join(runs or DEFAULT_RUNS)}"]


def cores(workers):
  """[set of one core] for each worker where the process may use that many cores, else
  [None] * workers (not pinned)."""
  allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
  if len(allowed) < workers:
    return [None] * workers
  return [{core} for core in allowed[:workers]]


def run_scenes(commands, out, workers):
  """Run `commands` ({scene: argv}) in order, `workers` at a time, each worker pinned to its
  core (`cores`); each scene's output in OUT/<scene>.log. Returns {scene: exit status}."""
  os.makedirs(out, exist_ok=True)
  queue, status, lock = list(commands), {}, threading.Lock()

  def work(core):
    while True:
      with lock:
        if not queue:
          return
        scene = queue.pop(0)
      print(f"{scene}: {' '.join(commands[scene][1:])}", flush=True)
      pin = None if core is None else (lambda: os.sched_setaffinity(0, core))
      code, _ = child.run_logged(commands[scene], os.path.join(out, f"{scene}.log"),
                                 preexec_fn=pin)
      print(f"{scene}: done (exit {code}), {os.path.join(out, scene, 'table.md')}", flush=True)
      status[scene] = code

  threads = [threading.Thread(target=work, args=(core,)) for core in cores(workers)]
  for thread in threads:
    thread.start()
  for thread in threads:
    thread.join()
  return status


def turned_on(record):
  """Whether a flip record's run turned its decision on (auto had it off): its first
  override is set to a true value other than the plain encoding ('posenc': cones off)."""
  value = next(iter(record["overrides"].values()), None)
  return bool(value) and value != "posenc"


def scene_summary(records):
  """One summary.jsonl row of a scene's results.jsonl `records` (with gains and regret);
  'busy_runs' names the runs whose machine record says it was busy (run/machine.py)."""
  auto_run = next((r for r in records if r["run"] == "auto"), {})
  best = max(regret.rivals(records), key=regret.score, default={})
  row = {"scene": records[0]["scene"], "auto_config": auto_run.get("base"),
         "auto_score": regret.score(auto_run), "auto_steps": auto_run.get("steps"),
         "budget_seconds": auto_run.get("seconds"), "best_run": best.get("run"),
         "best_score": regret.score(best) if best else None,
         "regret": records[0].get("regret"), "machine": auto_run.get("machine"), "runs": {},
         "busy_runs": [r["run"] for r in records if (r.get("machine") or {}).get("busy")]}
  for r in records:
    if r["run"] == "auto":
      continue
    row["runs"][r["run"]] = {
        "gain": r.get("gain"), "step_cost_ratio": r.get("step_cost_ratio"),
        "turned": "" if r["flipped"] == "representation" else
                  ("on" if turned_on(r) else "off"), "error": r.get("error"),
        "same_as_auto": bool(r.get("same_as_auto"))}
  return row


def columns(rows):
  """The run names of `rows`, flips in regret_plan.FLIPS's order, then the representations."""
  names = {name for row in rows for name in row["runs"]}
  flips = [f"flip/{d}" for d in regret_plan.FLIPS if f"flip/{d}" in names]
  return flips + sorted(names - set(flips))


def _flip_cell(run):
  if run is None:
    return ""
  if run.get("gain") is None:
    return "failed"
  ratio = run.get("step_cost_ratio")
  if run.get("same_as_auto"):  # auto's own config at this budget: the noise between two runs
    return f"= auto {run['gain']:+.2f}"
  return (f"{run['turned']} {run['gain']:+.2f}" if run["turned"] else f"{run['gain']:+.2f}") + (
      "" if ratio is None else f" ({ratio:.2f}×)")


def summary_table(rows):
  """table.md: one row per scene; each flip's cell 'on/off GAIN (step-cost ratio×)', the
  direction the flip turned auto's decision; the scene's cell names the runs whose machine was
  busy."""
  names = columns(rows)
  head = ["scene", "auto's config", "auto", "steps", "best run", "regret"] + names
  lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
  fmt = regret.format_cell
  for row in rows:
    busy = row.get("busy_runs")  # runs whose machine was busy while they trained
    scene = row["scene"] + (f" (busy: {', '.join(busy)})" if busy else "")
    cells = [scene, f"{row['auto_config']}.py", fmt(row["auto_score"], ".2f"),
             fmt(row["auto_steps"], "d"), row["best_run"] or "-", fmt(row["regret"], ".2f")]
    cells += [_flip_cell(row["runs"].get(name)) for name in names]
    lines.append("| " + " | ".join(cells) + " |")
  return "\n".join(lines) + "\n"


def picture(rows, path):
  """One panel per scene at `path`: each run's gain over auto (dB) against its step-cost ratio,
  the flips marked by the way they turned auto's decision. Returns None, or the line saying
  matplotlib is missing (nothing drawn)."""
  problem = report.missing_dependency()
  if problem:
    return problem
  from matplotlib import figure  # pylint: disable=import-outside-toplevel  (optional: [bench])
  across = min(4, len(rows))
  down = -(-len(rows) // across)
  fig = figure.Figure(figsize=(3.6 * across, 3.0 * down))
  axes = fig.subplots(down, across, squeeze=False).ravel()
  marks = {"on": ("^", "C3"), "off": ("v", "C0"), "": ("s", "C2")}
  for ax, row in zip(axes, rows):
    ax.scatter([1.0], [0.0], marker="o", color="k")
    for name, run in row["runs"].items():
      if run.get("gain") is None:
        continue
      marker, colour = marks[run["turned"]]
      ax.scatter(run["step_cost_ratio"], run["gain"], marker=marker, color=colour)
      ax.annotate(name.split("/")[1], (run["step_cost_ratio"], run["gain"]), fontsize=6,
                  textcoords="offset points", xytext=(3, 2))
    ax.axhline(0.0, color="grey", linewidth=0.8)
    ax.axvline(1.0, color="grey", linewidth=0.8)
    regret_text = "-" if row["regret"] is None else f"{row['regret']:.2f}"
    ax.set_title(f"{row['scene']} ({row['auto_config']}.py): regret {regret_text} dB",
                 fontsize=8)
    ax.tick_params(labelsize=7)
  for ax in axes[len(rows):]:
    ax.set_visible(False)
  fig.suptitle("each run against auto (●): ▲ a decision turned on, ▼ turned off, ■ another "
               "config", fontsize=9)
  fig.supxlabel("step-cost ratio (seconds per step / auto's)", fontsize=8)
  fig.supylabel("PSNR gain over auto (dB)", fontsize=8)
  fig.tight_layout()
  fig.savefig(path, dpi=110)
  return None


def summarize(out, scenes=None):
  """Rows of every OUT/<scene>/results.jsonl (of `scenes` only, where given), written to
  OUT/summary.jsonl, OUT/table.md and OUT/regret_table.png (`picture`). Returns the rows."""
  rows = []
  names = sorted(os.listdir(out)) if os.path.isdir(out) else []
  for scene in names:
    path = os.path.join(out, scene, "results.jsonl")
    if (scenes and scene not in scenes) or not os.path.isfile(path):
      continue
    scene_records = records_lib.read(path)
    if scene_records:  # stamped with the machine of auto's run, where it measured one
      rows.append(records_lib.stamp(scene_summary(scene_records)))
  if not rows:
    raise FileNotFoundError(f"--out={out}: no <scene>/results.jsonl to summarise")
  records_lib.write(os.path.join(out, "summary.jsonl"), rows)
  with open(os.path.join(out, "table.md"), "w") as f:
    f.write(summary_table(rows))
  problem = picture(rows, os.path.join(out, "regret_table.png"))
  if problem:
    print(f"no picture: {problem}", flush=True)
  return rows


def define_table_flags(values, argv):
  """The flags of `python -m nerf_jax.bench.regret_table` on the FlagValues `values`."""
  command_line.define_config(values, argv, "The config auto starts from (default auto); "
                             "--config.FIELD=VALUE overrides go to every scene's runs.")
  flags.DEFINE_list("scenes", list(SCENES), "Built-in scenes, run in this order.",
                    flag_values=values)
  flags.DEFINE_float("seconds", 60.0, "Wall-clock training budget of every run.",
                     flag_values=values, lower_bound=0.0)
  flags.DEFINE_string("out", "runs/regret_table", "Output folder: one folder and log per "
                      "scene, table.md and summary.jsonl.", flag_values=values)
  flags.DEFINE_integer("workers", 2, "Scenes run at once, each pinned to a core of its own.",
                       flag_values=values, lower_bound=1)
  flags.DEFINE_list("runs", [], "--runs of every scene's command (default "
                    f"{','.join(DEFAULT_RUNS)}).", flag_values=values)
  flags.DEFINE_bool("summarize", False, "Train nothing: write the table from OUT's results.",
                    flag_values=values)


def regret_table(values, spec, argv):
  """Run the scenes (unless --summarize), then write the table. Returns the rows."""
  del spec
  if not values.summarize:
    commands = {scene: scene_command(scene, values.seconds, values.out,
                                     passed_on(argv, values.runs))
                for scene in values.scenes}
    failed = {s: c for s, c in run_scenes(commands, values.out, values.workers).items() if c}
    for scene, code in failed.items():
      print(f"{scene}: exit {code}; see {os.path.join(values.out, scene + '.log')}", flush=True)
  rows = summarize(values.out, None if values.summarize else values.scenes)
  print(f"{len(rows)} scenes -> {os.path.join(values.out, 'table.md')}", flush=True)
  return rows


def regret_table_main(argv=None):
  """`python -m nerf_jax.bench.regret_table`."""
  given = list(sys.argv if argv is None else argv)
  command_line.run_command(define_table_flags, regret_table, standard.normalised_argv(given),
                           with_config=True)


if __name__ == "__main__":
  regret_table_main()
