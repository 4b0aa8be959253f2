"""Running a sweep: every planned configuration in a fresh subprocess (clean peak RSS, no shared
compile cache) that trains and measures it (timed_run.py) and hands back one record; the records
go to results.jsonl as they come, with results.md and the plots (report.py) rewritten after each.
"""

import dataclasses
import json
import os
import subprocess
import sys
import tempfile

from nerf_jax.run import machine as machine_lib
from nerf_jax.train import progress
from nerf_jax.bench import child, measure, records as records_lib, report, sweeps, timed_run


def run_isolated(config, options):
  """`timed_run.train_and_measure` in a fresh Python process; the record, or {'error': ...}."""
  with tempfile.TemporaryDirectory() as tmp:
    spec_path, record_path = os.path.join(tmp, "spec.json"), os.path.join(tmp, "record.json")
    with open(spec_path, "w") as f:
      json.dump({"config": config.to_json(), "options": dataclasses.asdict(options),
                 "record_path": record_path}, f)
    proc = subprocess.run([sys.executable, "-m", "nerf_jax.bench.timed_run", spec_path],
                          env=child.env(), check=False)  # its output is the sweep's
    if not os.path.exists(record_path):
      return {"error": f"worker exited with status {proc.returncode} without a record"}
    with open(record_path) as f:
      return json.load(f)


def run_sweep(request, options, out, command, in_process=False, dry_run=False):
  """Run every configuration `request` (a sweeps.Request) plans, measured as `options` (a
  timed_run.Options) says, writing results into `out`. command: the command line, for the
  report. in_process: run them in this process (peak RSS then accumulates). dry_run: list the
  runs and return []. Returns the records."""
  runs = sweeps.plan(request)
  each = (f"{request.steps} steps" if request.steps
          else f"{request.budget_seconds:g} s of training")
  print(f"{len(runs)} runs of {each} each, into {out}:", flush=True)
  for sweep, entry, scene, _ in runs:
    print(f"  {sweep}/{entry.label} on {scene}", flush=True)
  if dry_run:
    return []
  problem = report.missing_dependency()  # before any training, not after the first run
  if problem:
    raise ImportError(problem)
  os.makedirs(out, exist_ok=True)
  machine = measure.machine_info()
  dtypes = sorted({"float32"} | {c.model.dtype for *_, c in runs})
  machine["matmul_gflops"] = {d: measure.matmul_gflops(d, repeats=options.matmul_repeats)
                              for d in dtypes}
  run = timed_run.train_and_measure if in_process else run_isolated
  results = os.path.join(out, "results.jsonl")
  records_lib.write(results, [])
  records = []
  bar = progress.Progress(len(runs), "sweep")  # ETA from the runs done so far
  bar.update(0)  # the rate counts from now: every run, the first too, is a full run
  for i, (sweep, entry, scene, config) in enumerate(runs):
    bar.write(f"[{i + 1}/{len(runs)}] {sweep}/{entry.label} on {scene}")
    slug = "".join(c if c.isalnum() else "_" for c in f"{sweeps.scene_label(scene)}-{entry.label}")
    record = run(config, dataclasses.replace(options, eval_dir=os.path.join(out, "eval", slug)))
    record.update(sweep=sweep, label=entry.label, base=entry.base, overrides=entry.overrides,
                  scene=sweeps.scene_label(scene), mode=sweeps.mode(request), command=command,
                  eval_times=list(options.eval_times))
    # The sweep's machine and matmul peaks, with the run's own load while it trained.
    record = records_lib.stamp(record, {**machine, **record.get("machine", {})})
    records.append(record)
    records_lib.append(results, record)
    report.write_report(records, out)
    bar.write(summary(record))
    bar.update(i + 1, force=True)
  bar.close()
  return records


def summary(record):
  """One line of a finished run."""
  if "error" in record:
    return f"  failed: {record['error']}"
  busy = machine_lib.busy_note(record.get("machine"))
  return (f"  test PSNR {record['test_psnr']:.2f} dB, SSIM {record['test_ssim']:.3f}, "
          f"{record['steps']} steps in {record['train_seconds']:.1f} s "
          f"(compile {record['compile_seconds']:.1f} s), step {record['step_ms']:.1f} ms, "
          f"render {record['render_ms']:.0f} ms/frame{busy}")
