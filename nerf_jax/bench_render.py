"""Rendering speed and memory of a trained model: frame time, video time, peak RSS of big frames.

  python -m nerf_jax.bench_render --workdir=runs/fast_diffuse
  python -m nerf_jax.bench_render --workdir=runs/default_diffuse --sizes=100,800 --frames=120

Measured, for the newest checkpoint of --workdir, in one run:
  * frame ms: median of --repeats renders of the first test view's camera rescaled to
    --frame_size pixels on its longer side, after one warm-up render that compiles; for a
    model that marches (config.render.march), the plain path's frame ms too, side by side;
  * video s: the whole --frames-frame video (render_lib.render_video: orbit or spiral, rgb and
    depth mp4 written), timed from the call to the written files, its own compilation included;
  * big-frame RSS: for each side in --sizes, a fresh subprocess restores the model and renders
    one frame of that size; its peak RSS (getrusage) and its RSS after restoring, before
    rendering, show what the frame adds (chunked rendering keeps that to the output arrays).
Writes --out (default <workdir>/bench_render.json) and prints one line per figure.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from nerf_jax import bench, cli, render_lib, renderer


def _render_once(restored, size, march=None):
  """A blocking function rendering the first test view at `size` pixels on its longer side.

  march: None = the config's renderer; False = the plain path whatever the config says.
  """
  config, model, params, _, test_ds, near, far = restored
  if march is not None:
    config = config.copy_and_resolve_references()
    config.render.march = march
  draw = renderer.make_image_renderer(model, config, near, far)(params)
  background = render_lib.background_colour(config)
  # The test camera rescaled so its longer side has `size` pixels (same field of view).
  height, width, intrinsics = render_lib.scaled_camera(test_ds, size / max(test_ds.height,
                                                                           test_ds.width))
  return lambda: render_lib.render_pose(draw, test_ds.poses[0], height, width, intrinsics,
                                        config, background)


def big_frame_rss(workdir, size):
  """Run in a subprocess: {'size', 'rss_before_mb', 'peak_rss_mb', 'seconds'} of one frame."""
  restored = cli.restore_for_render(workdir)
  before = bench.peak_rss_mb()
  render = _render_once(restored, size)
  start = time.perf_counter()
  out = render()
  return {"size": size, "rss_before_mb": before, "peak_rss_mb": bench.peak_rss_mb(),
          "seconds": time.perf_counter() - start, "finite": bool(np.isfinite(out["rgb"]).all())}


def measure(workdir, frame_size=100, repeats=10, frames=120, sizes=(800,)):
  """The record: frame ms, video seconds and big-frame RSS of `workdir`'s model."""
  restored = cli.restore_for_render(workdir)
  config, model, params, train_ds, _, near, far = restored
  render = _render_once(restored, frame_size)
  frame_ms = [1e3 * s for s in bench.sample_seconds(render, repeats)]
  plain = {}
  if renderer.marches(config):  # the plain path side by side, for the ratio
    plain_ms = [1e3 * s for s in bench.sample_seconds(_render_once(restored, frame_size, False),
                                                      repeats)]
    plain = {"plain_frame_ms": plain_ms, "plain_frame_ms_median": float(np.median(plain_ms))}
  config.render.video_frames = frames
  with tempfile.TemporaryDirectory() as out_dir:
    start = time.perf_counter()
    render_lib.render_video(model, params, config, near, far, train_ds, out_dir,
                            show_progress=False)
    video_seconds = time.perf_counter() - start
  big = [_subprocess_frame(workdir, size) for size in sizes]
  return {"workdir": workdir, "encoding": config.model.encoding,
          "num_samples": config.num_samples, "num_fine_samples": config.num_fine_samples,
          "frame_size": frame_size, "frame_ms": frame_ms,
          "frame_ms_median": float(np.median(frame_ms)), **plain, "video_frames": frames,
          "video_seconds": video_seconds, "big_frames": big, "machine": bench.machine_info()}


def _subprocess_frame(workdir, size):
  command = [sys.executable, "-m", "nerf_jax.bench_render", f"--workdir={workdir}",
             f"--worker_size={size}"]
  result = subprocess.run(command, capture_output=True, text=True, check=True)
  return json.loads(result.stdout.strip().splitlines()[-1])


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
  parser.add_argument("--workdir", required=True, help="a training run with a checkpoint")
  parser.add_argument("--frame_size", type=int, default=100, help="side of the timed frame")
  parser.add_argument("--repeats", type=int, default=10, help="timed frame renders")
  parser.add_argument("--frames", type=int, default=120, help="frames of the timed video")
  parser.add_argument("--sizes", default="800", help="comma list of big-frame sides (RSS)")
  parser.add_argument("--out", default="", help="JSON output (default <workdir>/bench_render.json)")
  parser.add_argument("--worker_size", type=int, default=0, help=argparse.SUPPRESS)
  args = parser.parse_args(argv)
  if args.worker_size:
    print(json.dumps(big_frame_rss(args.workdir, args.worker_size)))
    return
  sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
  record = measure(args.workdir, args.frame_size, args.repeats, args.frames, sizes)
  out = args.out or os.path.join(args.workdir, "bench_render.json")
  with open(out, "w") as f:
    json.dump(record, f, indent=2)
  print(f"{args.frame_size}x{args.frame_size} frame: {record['frame_ms_median']:.1f} ms "
        f"(median of {args.repeats})")
  if "plain_frame_ms_median" in record:
    print(f"  plain path (no marching): {record['plain_frame_ms_median']:.1f} ms, "
          f"{record['plain_frame_ms_median'] / record['frame_ms_median']:.1f}x slower")
  print(f"{record['video_frames']}-frame video: {record['video_seconds']:.1f} s "
        "(compilation and mp4 writing included)")
  for big in record["big_frames"]:
    print(f"{big['size']}x{big['size']} frame: peak RSS {big['peak_rss_mb']:.0f} MB "
          f"({big['rss_before_mb']:.0f} MB before rendering), {big['seconds']:.1f} s")
  print(f"-> {out}")


if __name__ == "__main__":
  main()
