"""The render benchmark: its record is well formed and it renders the view it claims to.

Nothing here asserts on speed.
"""

import json

import numpy as np

from configs import debug
from nerf_jax import bench_render, cli, render_lib, renderer, train_lib


def _trained_workdir(tmp_path):
  config = debug.get_config()
  config.train.max_steps = 2
  config.data.scene_bound = 1.5  # a scene box: the model renders by marching
  config.render.after_training = False
  workdir = str(tmp_path / "run")
  train_lib.train_and_evaluate(config, workdir)
  return workdir


def test_render_bench_writes_frame_video_and_big_frame_figures(tmp_path):
  workdir = _trained_workdir(tmp_path)
  out = tmp_path / "render.json"
  bench_render.main([f"--workdir={workdir}", "--frame_size=24", "--repeats=2", "--frames=2",
                     "--sizes=40", f"--out={out}"])
  record = json.loads(out.read_text())
  assert len(record["frame_ms"]) == 2 and record["frame_ms_median"] > 0
  assert len(record["plain_frame_ms"]) == 2  # the plain path, side by side
  assert record["video_frames"] == 2 and record["video_seconds"] > 0
  (big,) = record["big_frames"]
  assert big["size"] == 40 and big["finite"]
  assert big["peak_rss_mb"] >= big["rss_before_mb"] > 0
  assert record["machine"]["cpu_count"] >= 1

  # At the dataset's own size the timed frame is exactly the first test view.
  restored = cli.restore_for_render(workdir)
  config, model, params, _, test_ds, near, far = restored
  frame = bench_render._render_once(restored, test_ds.width)()
  evaluator_frame = render_lib.render_pose(
      renderer.make_image_renderer(model, config, near, far)(params), test_ds.poses[0], test_ds.height, test_ds.width, test_ds.intrinsics, config,
      render_lib.background_colour(config))
  np.testing.assert_allclose(frame["rgb"], evaluator_frame["rgb"], atol=1e-6)
