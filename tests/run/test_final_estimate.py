"""A long final evaluation (+ video) says how long it will take, and how to shorten it, before it
starts (run/outputs.final_render_line); eval.test_every scores every N-th test view."""

import numpy as np
import pytest

from nerf_jax import cli
from nerf_jax.evaluate import evaluation
from nerf_jax.run import experiment, outputs
from tests.helpers import small_config

# 10 views of 8 x 8 of 'diffuse', views 5..9 held out: 5 test views of 64 pixels.
SMALL = {"data.scene": "diffuse", "data.num_views": 10, "data.image_size": 8,
         "data.holdout_from": 5, "train.max_steps": 1}


def test_seconds_are_the_rays_over_the_training_rate():
  # 3 views of 10 x 12 (360 rays), a 4-frame video of 10 x 12 (480), at 10 rays a second: 84 s.
  assert outputs.final_render_seconds(3 * 120, 4, 120, 10.0) == pytest.approx(84.0)
  assert outputs.final_render_seconds(500, 0, 999, 250.0) == pytest.approx(2.0)


def test_scored_views():
  assert evaluation.scored_views(5) == [0, 1, 2, 3, 4]
  assert evaluation.scored_views(10, 4) == [0, 4, 8]
  assert evaluation.scored_views(10, 4, max_views=2) == [0, 4]
  assert evaluation.scored_views(3, 1, max_views=2) == [0, 1]


def test_scored_views_keep_every_scale_where_the_views_have_scale_labels():
  labels = np.array([0, 1, 2, 3] * 4)  # mip-NeRF's multiscale test views cycle through scales
  assert evaluation.scored_views(16, 4) == [0, 4, 8, 12]  # a plain stride: one scale of four
  assert evaluation.scored_views(16, 4, labels=labels) == [0, 1, 2, 3]
  assert evaluation.scored_views(16, 2, labels=labels) == [0, 1, 2, 3, 8, 9, 10, 11]
  grouped = np.repeat(np.arange(2), 5)  # views grouped by scale: each group strided alone
  assert evaluation.scored_views(10, 2, labels=grouped) == [0, 2, 4, 5, 7, 9]
  assert evaluation.scored_views(16, 1, labels=labels) == list(range(16))


def test_the_line_of_a_long_evaluation():
  config = small_config(SMALL, **{"eval.test_every": 2, "render.after_training": True,
                                  "render.video_frames": 4})
  exp = experiment.setup(config)
  frames = 4 if outputs.video_writer_missing() is None else 0  # no mp4 writer: no video
  # Views 0, 2, 4 of 64 pixels and the frames' 64 each, at 1 ray a second.
  seconds = 3 * 64 + frames * 64
  line = outputs.final_render_line(exp, 1.0, long_seconds=seconds - 1)
  every = -(-2 * seconds // (seconds - 1))  # ceil(test_every * seconds / long_seconds)
  assert line.startswith("final evaluation: about ")
  assert "render 3 test views" in line
  assert f"({seconds:,} rays' worth at training's 1 rays/s)" in line
  assert f"--config.eval.test_every={max(2, every)}" in line
  assert ("--config.render.video_frames=0" in line) == bool(frames)
  assert outputs.final_render_line(exp, 1.0, long_seconds=seconds) is None
  assert outputs.final_render_line(exp, None) is None


def test_the_codes_fit_counts_in_the_estimate():
  # Codes fitted on each left half: 3 views x 7 steps x 12 rays = 252 fit rays, each a sixth of
  # a training ray's cost (42), beside the 3 x 64 pixels rendered.
  config = small_config(SMALL, **{"eval.test_every": 2, "eval.appearance": "left_half",
                                  "eval.fit_steps": 7, "eval.fit_rays": 12,
                                  "model.appearance_dims": 2})
  exp = experiment.setup(config)
  seconds = 3 * 64 + 42
  line = outputs.final_render_line(exp, 1.0, long_seconds=seconds - 1)
  assert "and fit their codes (252 rays)" in line and f"({seconds:,} rays' worth" in line
  assert "--config.eval.fit_steps=100" in line
  assert outputs.final_render_line(exp, 1.0, long_seconds=seconds) is None
  config.model.appearance_dims = 0  # no codes: nothing to fit
  assert outputs.fit_rays(config, 3) == 0


@pytest.mark.slow  # trains a 1-step run
def test_a_run_announces_a_long_evaluation_first_and_scores_every_nth_view(tmp_path, capsys,
                                                                              monkeypatch):
  monkeypatch.setattr(outputs, "LONG_FINAL_SECONDS", 0.0)
  result = cli.train(small_config(SMALL, **{"eval.test_every": 2}), str(tmp_path / "run"))
  assert [v["view"] for v in result["per_view"]] == [0, 2, 4]
  out = capsys.readouterr().out.splitlines()
  announced = [k for k, l in enumerate(out) if l.startswith("final evaluation: about ")]
  scored = [k for k, l in enumerate(out) if l.startswith("test PSNR")]
  assert len(announced) == 1 and announced[0] < scored[0]
  assert "--config.eval.test_every=" in out[announced[0]]
