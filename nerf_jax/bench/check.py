"""One command that checks a machine end to end (a GPU box above all): the README's main job, a
short training on each standard scene you have, and the quick test suite; then one table.

  python -m nerf_jax.bench.check                                    # main job + quick suite
  python -m nerf_jax.bench.check --lego=data/lego --fox=data/fox --fern=data/fern --seconds=60

Each stage runs in its own process under its own time limit, so a stage that fails or hangs
costs only its own time; the whole check ends within --total seconds (default 480: the quick
suite gets whatever time the trainings left). The scenes, with the configs the README names:
  lego  a Blender folder (transforms_train.json, ...): configs/detail.py
  fox   instant-ngp's data/nerf/fox as shipped: configs/capture.py, data.factor=4
  fern  an LLFF folder (poses_bounds.npy, images_8/): configs/llff.py, data.factor=8
The table (also written to --out/check.md) names the backend and device, and each stage's steps,
steps/s, PSNR and seconds. Processes share one GPU: memory is not preallocated.
"""

import json
import os
import re
import sys
import time

from absl import app, flags

from nerf_jax.bench import child

SCENES = {"lego": ("detail", {}), "fox": ("capture", {"data.factor": 4}),
          "fern": ("llff", {"data.factor": 8})}

FLAGS = flags.FLAGS
flags.DEFINE_string("lego", "", "A Blender folder of lego (empty: skipped).")
flags.DEFINE_string("fox", "", "instant-ngp's fox folder as shipped (empty: skipped).")
flags.DEFINE_string("fern", "", "LLFF's fern folder (empty: skipped).")
flags.DEFINE_float("seconds", 60.0, "Training seconds for each scene.")
flags.DEFINE_integer("total", 480, "Seconds for the whole check; the suite gets what is left.")
flags.DEFINE_string("out", "/tmp/nerf_jax_check", "Folder for the workdirs, logs and check.md.")
flags.DEFINE_string("tests", "tests", "The test folder for the quick suite (empty: skipped).")
flags.DEFINE_string("workers", "4", "pytest-xdist workers for the suite ('0': one process).")

TRAIN = "import sys; from nerf_jax import cli; cli.train_main(sys.argv)"
DEVICE = ("import jax; d = jax.devices()[0]; "
          "print(jax.default_backend(), '|', getattr(d, 'device_kind', d.platform), '|', "
          "jax.__version__)")


def _env():
  """The stages' environment: this process's path, no GPU preallocation."""
  return child.env(preallocate=False, own_code=False)


def device():
  """'backend | device kind | jax version' of this machine's first jax device."""
  return child.python_line(DEVICE, _env())


def train_row(name, config, overrides, out, timeout):
  """One table row: a training run of `config` with `overrides` (dotted field -> value)."""
  workdir = os.path.join(out, name)
  args = [sys.executable, "-c", TRAIN, f"--config={config}", f"--workdir={workdir}",
          *(f"--config.{k}={v}" for k, v in overrides.items())]
  code, seconds = child.run_logged(args, os.path.join(out, f"{name}.log"), timeout, _env())
  row = {"stage": name, "config": config, "status": "ok" if code == 0 else f"exit {code}",
         "seconds": seconds}
  path = os.path.join(workdir, "metrics.json")
  if code == 0 and os.path.exists(path):
    metrics = json.load(open(path))
    row.update(steps=metrics["steps"], psnr=metrics["psnr"],
               steps_per_s=metrics["steps"] / max(metrics["train_seconds"], 1e-9))
  return row


def suite_row(out, tests, workers, timeout):
  """The quick suite (`pytest -m "not slow"`) as a row: passed, failed and errors counted."""
  log = os.path.join(out, "suite.log")
  code, seconds = child.run_logged([sys.executable, "-m", "pytest", tests, "-m", "not slow",
                                    "-q", "-n", workers, "-p", "no:cacheprovider"], log,
                                   timeout, _env())
  text = open(log).read()
  counts = {k: int(n) for n, k in re.findall(r"(\d+) (passed|failed|errors?|skipped)", text)}
  summary = ", ".join(f"{n} {k}" for k, n in counts.items()) or "no summary"
  return {"stage": "quick suite", "config": "-", "seconds": seconds,
          "status": f"{summary}" + ("" if code == 0 else f" (exit {code})")}


def table(rows, machine):
  """The check as a markdown table."""
  lines = [f"backend | device | jax: {machine}", "",
           "| stage | config | steps | steps/s | PSNR (dB) | seconds | status |",
           "|---|---|---:|---:|---:|---:|---|"]
  for r in rows:
    steps = f"{r['steps']:,}" if "steps" in r else "-"
    rate = f"{r['steps_per_s']:.1f}" if "steps_per_s" in r else "-"
    psnr = f"{r['psnr']:.2f}" if "psnr" in r else "-"
    lines.append(f"| {r['stage']} | {r['config']} | {steps} | {rate} | {psnr} | "
                 f"{r['seconds']:.0f} | {r['status']} |")
  return "\n".join(lines)


def main(_):
  os.makedirs(FLAGS.out, exist_ok=True)
  end = time.perf_counter() + FLAGS.total
  left = lambda: end - time.perf_counter()
  machine = device()
  print(f"checking on {machine}; logs in {FLAGS.out}", flush=True)
  # The README's main job (the default config on the built-in scene), then each scene given.
  rows = [train_row("main job", "default", {}, FLAGS.out, min(left(), 300))]
  print(table(rows, machine).splitlines()[-1], flush=True)
  for name, (config, overrides) in SCENES.items():
    folder = getattr(FLAGS, name)
    if not folder:
      continue
    fields = {"data.path": folder, "train.max_seconds": FLAGS.seconds,
              "render.video_frames": 0, **overrides}
    # Setup, compilation and the final evaluation come on top of the training seconds.
    rows.append(train_row(name, config, fields, FLAGS.out, min(left(), FLAGS.seconds + 150)))
    print(table(rows, machine).splitlines()[-1], flush=True)
  if FLAGS.tests:
    rows.append(suite_row(FLAGS.out, FLAGS.tests, FLAGS.workers, left()))
  report = table(rows, machine)
  with open(os.path.join(FLAGS.out, "check.md"), "w") as f:
    f.write(f"{time.strftime('%Y-%m-%d')}\n\n{report}\n")
  print(report)


if __name__ == "__main__":
  app.run(main)
