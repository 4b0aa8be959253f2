"""The benchmark's report: the results.md table, and plots of PSNR over training time and of
the Pareto fronts of quality against cost.

A record is one run's dict (see timed_run.train_and_measure) with 'scene', 'sweep', 'label',
'machine', 'mode' and 'command' added by runner.run_sweep; a failed run has an 'error' instead
of numbers. Plots have one panel per scene. matplotlib is imported only here, through its
object-oriented API (no pyplot, no global backend), so it stays an optional dependency: the
`bench` extra.
"""

import math
import os

from nerf_jax.run import machine as machine_lib  # its RULE, in the header

PLOTS = ("psnr_vs_time.png", "pareto_render.png", "pareto_train.png")
MISSING_MATPLOTLIB = 'plots need matplotlib: pip install -e ".[bench]"'


def missing_dependency():
  """None if the plots can be drawn, else the one line saying what to install."""
  try:
    import matplotlib.figure  # noqa: F401  pylint: disable=import-outside-toplevel,unused-import
  except ImportError:
    return MISSING_MATPLOTLIB
  return None


def pareto_front(costs, scores):
  """Indices of the runs no other run beats (lower cost, higher score), in order of cost.

  costs, scores: sequences of float of the same length.
  """
  order = sorted(range(len(costs)), key=lambda i: (costs[i], -scores[i]))
  front, best = [], -math.inf
  for i in order:
    if scores[i] > best:
      front.append(i)
      best = scores[i]
  return front


def run_name(record, records):
  """The label, prefixed by the sweep when the records come from several sweeps."""
  several = len({r["sweep"] for r in records}) > 1
  return f"{record['sweep']}/{record['label']}" if several else record["label"]


def _by_scene(records):
  groups = {}
  for r in records:
    groups.setdefault(r["scene"], []).append(r)
  return groups


def _figure(num_panels):
  from matplotlib.figure import Figure
  fig = Figure(figsize=(5.5 * num_panels, 4.2), layout="constrained")
  return fig, fig.subplots(1, num_panels, squeeze=False)[0]


def plot_psnr_vs_time(records, path):
  """One curve per configuration: probe PSNR against train seconds."""
  groups = _by_scene(records)
  fig, axes = _figure(len(groups))
  for ax, (scene, runs) in zip(axes, groups.items()):
    for r in runs:
      probes = sorted(r["probes"], key=lambda p: p["seconds"])
      line, = ax.plot([p["seconds"] for p in probes], [p["psnr"] for p in probes], marker="o",
                      markersize=3, label=run_name(r, records))
      # Until compilation ends the model is the untrained one: show that stretch dotted.
      ax.plot([0.0, r["compile_seconds"]], [probes[0]["psnr"]] * 2, color=line.get_color(),
              linestyle=":", marker="|", markersize=8)
    ax.set_title(f"{scene}: PSNR while training")
    ax.set_xlabel("train seconds (compilation, dotted, included; probes excluded)")
    ax.set_ylabel("PSNR on the probe views (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
  fig.savefig(path, dpi=110)


def plot_pareto(records, cost_key, cost_label, path):
  """Test PSNR against `record[cost_key]`, the Pareto front drawn and its points ringed."""
  groups = _by_scene(records)
  fig, axes = _figure(len(groups))
  for ax, (scene, runs) in zip(axes, groups.items()):
    costs = [r[cost_key] for r in runs]
    scores = [r["test_psnr"] for r in runs]
    front = pareto_front(costs, scores)
    ax.scatter(costs, scores, color="tab:blue", zorder=2)
    ax.plot([costs[i] for i in front], [scores[i] for i in front], color="tab:red",
            drawstyle="steps-post", marker="o", markersize=9, markerfacecolor="none",
            label="Pareto front", zorder=3)
    for r, x, y in zip(runs, costs, scores):
      ax.annotate(run_name(r, records), (x, y), textcoords="offset points", xytext=(4, 4),
                  fontsize=7)
    if min(costs) > 0 and max(costs) / min(costs) > 10:
      ax.set_xscale("log")
    ax.margins(x=0.15, y=0.1)  # room for the labels
    ax.set_title(f"{scene}: test PSNR vs {cost_label}")
    ax.set_xlabel(cost_label)
    ax.set_ylabel("test PSNR (dB, mean over test views)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
  fig.savefig(path, dpi=110)


def samples_per_step(record):
  """Rays per step × samples per ray (coarse + fine) of a record."""
  config = record["config"]
  return record["rays_per_step"] * (config["num_samples"] + config["num_fine_samples"])


def plot_scaling(records, path):
  """Median step ms and samples/s against samples per step (log-log), one panel per scene."""
  groups = _by_scene(records)
  fig, axes = _figure(len(groups))
  for ax, (scene, runs) in zip(axes, groups.items()):
    runs = sorted(runs, key=samples_per_step)
    work = [samples_per_step(r) for r in runs]
    ax.loglog(work, [r["step_ms"] for r in runs], marker="o", label="step ms (median)")
    ideal = runs[-1]["step_ms"] / work[-1]  # linear through the largest run
    ax.loglog(work, [ideal * w for w in work], linestyle=":", color="gray", label="linear")
    rate = ax.twinx()
    rate.semilogx(work, [w / r["step_ms"] / 1e3 for w, r in zip(work, runs)], color="tab:red",
                  marker="s", label="samples/s (M)")
    rate.set_ylabel("million samples per second", color="tab:red")
    for r, x, y in zip(runs, work, [r["step_ms"] for r in runs]):
      ax.annotate(r["label"], (x, y), textcoords="offset points", xytext=(4, -10), fontsize=6)
    ax.set_title(f"{scene}: step time against work per step")
    ax.set_xlabel("samples per step (rays × samples per ray)")
    ax.set_ylabel("train step ms")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="upper left")
  fig.savefig(path, dpi=110)


def write_plots(records, out_dir):
  """The PNGs of `records` (runs that did not fail) in `out_dir`; returns their paths.

  Always the three of PLOTS; also scaling.png when the scaling sweep ran.
  """
  if not records:
    return []
  paths = [os.path.join(out_dir, name) for name in PLOTS]
  plot_psnr_vs_time(records, paths[0])
  plot_pareto(records, "render_ms", "render ms per 100×100 frame", paths[1])
  plot_pareto(records, "train_seconds", "train seconds (compilation included)", paths[2])
  scaling = [r for r in records if r["sweep"] == "scaling"]
  if len(scaling) >= 2:
    paths.append(os.path.join(out_dir, "scaling.png"))
    plot_scaling(scaling, paths[-1])
  return paths


def _fmt(value, spec):
  return "–" if value is None else format(value, spec)


def shown_times(records):
  """Probe times worth a column: those within the longest run's training time."""
  ok = [r for r in records if "error" not in r]
  if not ok:
    return []
  longest = max(r["train_seconds"] for r in ok)
  times = ok[0]["eval_times"]
  return [t for t in times if t <= longest] or times[:1]


# Columns shown when a run has them: LPIPS, and the geometry scores of data with true opacity
# and depth (evaluation.geometry_errors).
OPTIONAL_COLUMNS = (("test_lpips", "LPIPS"), ("test_depth_error", "depth err"),
                    ("test_empty_opacity", "empty opacity"), ("test_floaters", "floaters"))


def load_cell(machine):
  """The machine column: 'busy: WHY' or 'idle' by the record's verdict (run/machine.py), '–'
  for a record without one."""
  if not isinstance(machine, dict) or "busy" not in machine:
    return "–"
  return f"busy: {machine.get('busy_why')}" if machine["busy"] else "idle"


def table_lines(records):
  """Markdown table lines, one row per record; the last column says whether the machine was
  busy while the run trained (run/machine.py's verdict)."""
  times = shown_times(records)
  extra = [(key, label) for key, label in OPTIONAL_COLUMNS if any(r.get(key) is not None
                                                                  for r in records)]
  head = (["scene", "config", "test PSNR", "SSIM"] + [label for _, label in extra] +
          [f"PSNR@{t:g}s" for t in times] +
          ["steps", "train s (incl. compile)", "compile s", "step ms", "rays/s",
           "MLP GFLOP/s (% peak)", "render ms/frame", "params", "peak RSS MB", "machine"])
  lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
  for r in records:
    name = run_name(r, records)
    if "error" in r:
      lines.append(f"| {r['scene']} | {name} | failed: {r['error']} |")
      continue
    cells = [r["scene"], name, _fmt(r["test_psnr"], ".2f"), _fmt(r["test_ssim"], ".3f")]
    cells += [_fmt(r.get(key), ".3f") for key, _ in extra]
    cells += [_fmt(r["psnr_at"].get(f"{t:g}"), ".2f") for t in times]
    cells += [str(r["steps"]), _fmt(r["train_seconds"], ".1f"), _fmt(r["compile_seconds"], ".1f"),
              _fmt(r["step_ms"], ".1f"), _fmt(r["rays_per_second"], ",.0f"),
              f"{r['mlp_gflops']:.1f} ({100 * r['peak_fraction']:.0f}%)",
              _fmt(r["render_ms"], ".0f"), f"{r['params']:,}", _fmt(r["peak_rss_mb"], ".0f"),
              load_cell(r.get("machine"))]
    lines.append("| " + " | ".join(cells) + " |")
  return lines


def header_lines(record):
  """The lines above the table: the command, machine, versions, matmul peak and budget."""
  m, mode = record["machine"], record["mode"]
  peaks = ", ".join(f"{d} {max(v.values()):.1f}" for d, v in m["matmul_gflops"].items())
  if mode["kind"] == "steps":
    budget = f"equal steps: {mode['steps']} steps per run"
  else:
    budget = (f"equal wall clock: {mode['budget_seconds']:g} s per run, compilation included, "
              "PSNR probes excluded; " + ("lr schedule fitted to the budget"
                                          if mode["schedule"] == "fitted" else
                                          "max_steps and lr schedule of the config"))
  return [
      "# Benchmark results", "",
      f"`{record['command']}`", "",
      f"* machine: {m['cpu_model']}, {m['cpu_count']} cores, {m['backend']} "
      f"({m['device_kind']}), load average at start {m['load_average']}",
      f"* versions: jax {m['jax']}, jaxlib {m['jaxlib']}, flax {m['flax']}, optax "
      f"{m['optax']}, Python {m['python']}, {m['platform']}; code {m.get('git') or 'unknown'}",
      f"* machine: 'busy' where the machine was busy while the run trained ({machine_lib.RULE}; "
      "`machine` in results.jsonl)",
      f"* dense matmul peak (GFLOP/s) at the start: {peaks}; each run's % uses its own "
      "measurement, taken just before it trained (`matmul_peak_gflops` in results.jsonl)",
      f"* budget: {budget}",
      "* PSNR@t: test PSNR on the probe views of the model as it was t train seconds in; "
      "test PSNR and SSIM: mean over all test views at the end", ""]


def write_report(records, out_dir):
  """results.md and the plots for `records`."""
  lines = header_lines(records[0]) + table_lines(records)
  with open(os.path.join(out_dir, "results.md"), "w") as f:
    f.write("\n".join(lines) + "\n")
  write_plots([r for r in records if "error" not in r], out_dir)
