"""Tests of the evaluation's per-scale scores (evaluation.scores_by_scale, metrics.json's
by_scale and mean_over_scales) against per-view scores averaged here, and a tiny end-to-end run
on mip-NeRF's multiscale format converted from a built-in scene."""

import json

import numpy as np
import pytest

from nerf_jax.data import export, convert_multiscale, scenes
from nerf_jax.evaluate import evaluation
from nerf_jax.run import train_lib
from tests.helpers import TINY_GRID, small_config


def test_by_scale_is_each_labels_view_mean_and_their_mean():
  per_view = [{"view": 0, "label": "0", "psnr": 20.0, "ssim": 0.5, "lpips": 0.3},
              {"view": 1, "label": "1", "psnr": 25.0, "ssim": 0.7},
              {"view": 2, "label": "0", "psnr": 22.0, "ssim": 0.6, "lpips": 0.1},
              {"view": 3, "label": "1", "psnr": 29.0, "ssim": 0.9}]
  got = evaluation.scores_by_scale(per_view)
  assert got["by_scale"] == {"0": {"psnr": 21.0, "ssim": 0.55, "lpips": 0.2, "views": 2},
                             "1": {"psnr": 27.0, "ssim": 0.8, "views": 2}}
  # lpips is left out of the mean: one label has none (images too small for it).
  assert got["mean_over_scales"] == pytest.approx({"psnr": 24.0, "ssim": 0.675})


@pytest.mark.slow
def test_a_run_on_converted_multiscale_data_scores_each_scale(tmp_path):
  fog = scenes.make_dataset("fog", num_views=6, height=16, width=16, focal=22.2)
  export.export_blender(fog, str(tmp_path / "blender"), split_at=4, background=fog.background)
  convert_multiscale.convert(str(tmp_path / "blender"), str(tmp_path / "ms"), levels=3)
  config = small_config({**TINY_GRID, "data.path": str(tmp_path / "ms"),
                         "data.background": "white", "train.max_steps": 10}, base="fast")
  train_lib.train_and_evaluate(config, str(tmp_path / "run"))
  metrics = json.load(open(tmp_path / "run" / "metrics.json"))
  per_view = metrics["per_view"]
  assert [v["label"] for v in per_view] == ["0", "1", "2"] * 2
  for label in "012":
    psnrs = [v["psnr"] for v in per_view if v["label"] == label]
    assert metrics["by_scale"][label]["views"] == 2
    np.testing.assert_allclose(metrics["by_scale"][label]["psnr"], np.mean(psnrs), rtol=1e-12)
  np.testing.assert_allclose(metrics["mean_over_scales"]["psnr"],
                             np.mean([metrics["by_scale"][s]["psnr"] for s in "012"]))
  np.testing.assert_allclose(metrics["psnr"], np.mean([v["psnr"] for v in per_view]))
