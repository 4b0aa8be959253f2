"""The render benchmark: its record is well formed and it renders the view it claims to.

Nothing here asserts on speed.
"""

import json

import jax.numpy as jnp
import numpy as np
import pytest
from absl import flags

from nerf_jax.backend import errors
from nerf_jax.render import renderer
from nerf_jax.run import experiment
from nerf_jax.run import train_lib
from nerf_jax.bench import render
from nerf_jax.cameras.rays import Rays, get_rays
from tests.bench.test_records import assert_stamped
from tests.helpers import PATHS_RTOL, jitted, requires_ffmpeg, small_config


def _trained_workdir(tmp_path):
  config = small_config({"train.max_steps": 2,
                         "data.scene_bound": 1.5})  # a scene box: the model renders by marching
  workdir = str(tmp_path / "run")
  train_lib.train_and_evaluate(config, workdir)
  return workdir


@pytest.mark.slow  # the big frame is rendered in a process of its own
@requires_ffmpeg
def test_render_bench_writes_frame_video_and_big_frame_figures(tmp_path, capsys):
  workdir = _trained_workdir(tmp_path)
  out = tmp_path / "render.json"
  argv = ["nerf_jax.bench.render", f"--workdir={workdir}", "--frame_size=24", "--repeats=2",
          "--frames=2", "--sizes=40", f"--out={out}"]
  values = flags.FlagValues()  # private: absl's global flags hold each name once per process
  render.define_render_flags(values)
  errors.parse_flags(argv, values)
  render.render_speed(values)
  assert capsys.readouterr().out.strip().splitlines()[-1] == f"-> {out}"
  record = json.loads(out.read_text())
  assert len(record["frame_ms"]) == 2 and record["frame_ms_median"] > 0
  assert len(record["plain_frame_ms"]) == 2  # the plain path, side by side
  assert record["video_frames"] == 2 and record["video_seconds"] > 0
  (big,) = record["big_frames"]  # measured by `python -m nerf_jax.bench.render` in a subprocess
  assert big["size"] == 40 and big["finite"]
  assert big["peak_rss_mb"] >= big["rss_before_mb"] > 0
  assert record["machine"]["cpu_count"] >= 1
  assert_stamped(record, record["machine"])  # bench/records.py's date and code revision

  # At the dataset's own size the timed frame is the first test view, checked against an
  # independent path: rays from rays.get_rays, every ray in one RayRenderer.render call (no
  # image renderer, no marching). The marched frame may differ by the documented bound: the
  # skipped cells' density along the box diagonal, plus the light left behind a stopped ray.
  exp, state = experiment.restore(workdir)
  test = exp.test_ds
  height, width, intrinsics = exp.camera(1.0)  # the frame's camera: the training one
  assert (height, width) == (test.height, test.width)
  np.testing.assert_allclose(intrinsics, test.intrinsics)
  origins, directions = get_rays(test.height, test.width, test.focal,
                                 jnp.asarray(test.poses[0]), exp.pixel_center)
  rays = Rays.create(origins, directions, exp.near, exp.far)
  ref = renderer.final(jitted(exp.renderer.render)(state.variables, rays))
  config = exp.config
  bound = 1.0 - np.exp(-config.render.march_threshold * 2.0 * np.sqrt(3.0)
                       * config.data.scene_bound) + config.render.min_transmittance
  size = max(test.height, test.width)
  marched = render.frame_renderer(exp, state.variables, size)()
  plain = render.frame_renderer(exp, state.variables, size, march=False)()
  np.testing.assert_allclose(plain["rgb"], ref["rgb"], rtol=PATHS_RTOL, atol=1e-5)
  np.testing.assert_allclose(plain["depth"], ref["depth"], rtol=PATHS_RTOL, atol=1e-4)
  assert np.max(np.abs(marched["acc"] - ref["acc"])) <= bound
  assert np.max(np.abs(marched["rgb"] - ref["rgb"])) <= 2 * bound
