"""Rendering speed and memory of a trained model: frame time, video time, peak RSS of big frames.

  python -m nerf_jax.bench.render --workdir=runs/fast_diffuse
  python -m nerf_jax.bench.render --workdir=runs/default_diffuse --sizes=100,800 --frames=120

Measured, for the newest checkpoint of --workdir (experiment.restore), in one run:
  * frame ms: median of --repeats renders of the first test view's pose through the training
    camera scaled to --frame_size pixels on its longer side (Experiment.camera), from pose to
    pixels, after one warm-up render that compiles; for a model that marches
    (image_renderer.marches), the plain path's frame ms too, side by side;
  * video s: the whole --frames-frame video (outputs.render_video: orbit or spiral, rgb and
    depth mp4 written), timed from the call to the written files, its own compilation included;
  * big-frame RSS: for each side in --sizes, a fresh subprocess restores the model and renders
    one frame of that size; its peak RSS (getrusage) and its RSS after restoring, before
    rendering, show what the frame adds (chunked rendering keeps that to the output arrays).
Writes --out (default <workdir>/bench_render.json) and prints one line per figure. The flags
are at the end of this module (define_render_flags).
"""

import dataclasses
import json
import os
import sys
import tempfile
import time

import numpy as np
from absl import flags

from nerf_jax.render import background, image_renderer
from nerf_jax.run import experiment, outputs
from nerf_jax.bench import child, command_line, measure, records


def frame_renderer(exp, variables, size, march=None):
  """A blocking function rendering the first test view's pose at `size` pixels on the longer
  side of the training camera; it returns the numpy dict rgb [H, W, 3], depth, acc.

  march: None = the config's renderer; False = the plain path whatever the config says.
  """
  if march is not None:
    exp = dataclasses.replace(exp, image=dataclasses.replace(exp.image, march=march))
  draw = image_renderer.make_image_renderer(exp.renderer, exp.image)(variables)
  bg = background.parse(exp.config.data.background)
  camera = exp.camera(size / max(exp.train_ds.height, exp.train_ds.width))
  pose = exp.test_ds.poses[0]
  return lambda: draw(exp.rays(pose, camera), bg)


def big_frame_rss(workdir, size):
  """Run in a subprocess: {'size', 'rss_before_mb', 'peak_rss_mb', 'seconds', 'finite'}."""
  exp, state = experiment.restore(workdir)
  before = measure.peak_rss_mb()
  render = frame_renderer(exp, state.variables, size)
  start = time.perf_counter()
  out = render()
  return {"size": size, "rss_before_mb": before, "peak_rss_mb": measure.peak_rss_mb(),
          "seconds": time.perf_counter() - start, "finite": bool(np.isfinite(out["rgb"]).all())}


def measure_workdir(workdir, frame_size=100, repeats=10, frames=120, sizes=(800,)):
  """The record: frame ms, video seconds and big-frame RSS of `workdir`'s model."""
  exp, state = experiment.restore(workdir)
  variables, config = state.variables, exp.config
  frame_ms = [1e3 * s for s in measure.sample_seconds(frame_renderer(exp, variables, frame_size),
                                                      repeats)]
  plain = {}
  if image_renderer.marches(exp.renderer, exp.image):  # the plain path side by side, for the ratio
    plain_ms = [1e3 * s for s in measure.sample_seconds(
        frame_renderer(exp, variables, frame_size, march=False), repeats)]
    plain = {"plain_frame_ms": plain_ms, "plain_frame_ms_median": float(np.median(plain_ms))}
  config.render.video_frames = frames
  with tempfile.TemporaryDirectory() as out_dir:
    start = time.perf_counter()
    outputs.render_video(exp, variables, out_dir, show_progress=False)
    video_seconds = time.perf_counter() - start
  big = [_subprocess_frame(workdir, size) for size in sizes]
  return {"workdir": workdir, "encoding": config.model.encoding,
          "num_samples": config.num_samples, "num_fine_samples": config.num_fine_samples,
          "frame_size": frame_size, "frame_ms": frame_ms,
          "frame_ms_median": float(np.median(frame_ms)), **plain, "video_frames": frames,
          "video_seconds": video_seconds, "big_frames": big, "machine": measure.machine_info()}


def _subprocess_frame(workdir, size):
  command = [sys.executable, "-m", "nerf_jax.bench.render", f"--workdir={workdir}",
             f"--worker_size={size}"]
  return child.json_line(command)


def summary_lines(record, repeats):
  """What the command prints: one line per figure of `record`."""
  lines = [f"{record['frame_size']}x{record['frame_size']} frame: "
           f"{record['frame_ms_median']:.1f} ms (median of {repeats})"]
  if "plain_frame_ms_median" in record:
    lines.append(f"  plain path (no marching): {record['plain_frame_ms_median']:.1f} ms, "
                 f"{record['plain_frame_ms_median'] / record['frame_ms_median']:.1f}x slower")
  lines.append(f"{record['video_frames']}-frame video: {record['video_seconds']:.1f} s "
               "(compilation and mp4 writing included)")
  for big in record["big_frames"]:
    lines.append(f"{big['size']}x{big['size']} frame: peak RSS {big['peak_rss_mb']:.0f} MB "
                 f"({big['rss_before_mb']:.0f} MB before rendering), {big['seconds']:.1f} s")
  return lines


# ---------------------------------------------------------------- python -m nerf_jax.bench.render


def define_render_flags(values, argv=None):
  """The flags of `python -m nerf_jax.bench.render` on the FlagValues `values`."""
  del argv  # no config flag: the workdir's saved config is the config
  flags.DEFINE_string("workdir", None, "A training run with a checkpoint.", flag_values=values,
                      required=True)
  flags.DEFINE_integer("frame_size", 100, "Longer side of the timed frame, pixels.",
                       flag_values=values, lower_bound=1)
  flags.DEFINE_integer("repeats", 10, "Timed frame renders.", flag_values=values, lower_bound=1)
  flags.DEFINE_integer("frames", 120, "Frames of the timed video.", flag_values=values,
                       lower_bound=1)
  flags.DEFINE_list("sizes", ["800"], "Big-frame sides whose peak RSS to measure.",
                    flag_values=values)
  flags.DEFINE_string("out", "", "JSON output (default <workdir>/bench_render.json).",
                      flag_values=values)
  flags.DEFINE_integer("worker_size", 0, "Internal: render one frame of this side in this "
                       "process and print its RSS record.", flag_values=values)


def render_speed(values, spec="", argv=None):
  """Measure the parsed flags' workdir, write the record and print its lines."""
  del spec, argv
  if not os.path.isdir(values.workdir):
    raise FileNotFoundError(f"--workdir={values.workdir}: no such directory")
  if values.worker_size:
    print(json.dumps(big_frame_rss(values.workdir, values.worker_size)))
    return None
  try:
    sizes = [int(s) for s in values.sizes]
  except ValueError:
    raise ValueError(f"--sizes={','.join(values.sizes)}: expected a comma list of "
                     "pixels") from None
  record = measure_workdir(values.workdir, values.frame_size, values.repeats, values.frames,
                           sizes)
  record = records.stamp(record)  # jax runs here already: describe() costs nothing more
  out = values.out or os.path.join(values.workdir, "bench_render.json")
  with open(out, "w") as f:
    json.dump(record, f, indent=2)
  print("\n".join(summary_lines(record, values.repeats) + [f"-> {out}"]))
  return record


def render_speed_main(argv=None):
  """`python -m nerf_jax.bench.render`."""
  command_line.run_command(define_render_flags, render_speed, argv,
                           with_config=False)


if __name__ == "__main__":
  render_speed_main()
