"""Training learns the scene: quality above trivial answers, depth, and each effect shown to work.

Most checks read the one shared trained run (conftest.py's trained_run). A check passes only if the
model beats answers that learn nothing — the background alone and the mean training image,
scored on the same test views — by helpers.TRIVIAL_MARGIN_DB.
"""

import json

import numpy as np
import pytest

from nerf_jax.run import builders, experiment
from nerf_jax.run.signature import init_state
from tests.helpers import assert_beats_trivial, trivial_psnrs
from tests.helpers import small_config

# Bounds on the shared run's depth on opaque test pixels (scene units; their true depths have a
# standard deviation of 0.26). Measured: median |error| 0.19, almost all of it a bias (the
# learned surface lies 0.19 behind the true one after 600 steps; 0.09 without the bias), and a
# correlation of 0.76 with the true depth (0.59 once rays went through pixel centres and density
# became per world length), which no constant depth answer has. The bias is the tiny model's,
# not a convention or a sampling error: it does not follow the sample spacing (16 samples over
# [2, 6]: 0.197; 64: 0.191), the simulator's depth and the renderer's are both E[t] along the
# un-normalised ray (z-depth), and the 400 px `detail` runs have a 0.020 median depth error.
DEPTH_MEDIAN_BOUND = 0.3
DEPTH_MIN_CORRELATION = 0.5


def test_shared_run_beats_the_trivial_answers_and_the_untrained_model(trained_run):
  workdir, result = trained_run
  exp, _ = experiment.restore(str(workdir))
  assert_beats_trivial(result["psnr"], exp)
  untrained = builders.make_evaluator(exp)(init_state(exp).variables)["psnr"]
  assert result["psnr"] > untrained + 5.0, (untrained, result["psnr"])
  # What the run wrote says the same.
  saved = json.loads((workdir / "metrics.json").read_text())
  assert saved["psnr"] == pytest.approx(result["psnr"]) and saved["steps"] == 600
  assert {"psnr", "ssim", "per_view", "train_seconds", "steps"} <= set(saved)
  assert len(saved["per_view"]) == len(exp.test_ds) == 4
  records = [json.loads(l) for l in (workdir / "metrics.jsonl").read_text().splitlines()]
  assert [r["step"] for r in records] == [300, 600, 600]  # 2 log steps + the final eval
  assert records[0]["eval_psnr"] < records[1]["eval_psnr"]  # still improving at step 300
  assert records[-1]["eval_psnr"] == pytest.approx(result["psnr"]) and records[-1]["final"]


def test_trivial_answers_score_what_they_are():
  """The trivial scores themselves, against a brute-force PSNR on one tiny dataset."""
  exp = experiment.setup(small_config())
  scores = trivial_psnrs(exp)
  test = exp.test_ds.images  # black background: the targets are the images themselves
  mean = exp.train_ds.images.mean(0)
  brute = lambda guess: np.mean([-10 * np.log10(np.mean((guess - t) ** 2)) for t in test])
  assert scores["background"] == pytest.approx(brute(np.zeros(3)), abs=1e-3)
  assert scores["mean"] == pytest.approx(brute(mean), abs=1e-3)
  assert scores["mean"] > scores["background"]


def test_shared_run_depth_matches_the_scene_on_opaque_pixels(trained_run):
  workdir, _ = trained_run
  exp, state = experiment.restore(str(workdir))
  test_ds = exp.test_ds
  predicted, true = [], []

  def on_view(i, out, truth):
    opaque = test_ds.accs[i] > 0.999
    predicted.append(out["depth"][opaque])
    true.append(test_ds.depths[i][opaque])
  builders.make_evaluator(exp)(state.variables, on_view=on_view)
  predicted, true = np.concatenate(predicted), np.concatenate(true)
  assert len(true) > 200
  assert np.median(np.abs(predicted - true)) < DEPTH_MEDIAN_BOUND
  assert np.corrcoef(predicted, true)[0, 1] > DEPTH_MIN_CORRELATION
