"""data.background = 'auto' (the default): Blender (NeRF-synthetic) folders of RGBA images are
loaded, rendered and scored on white, as every published table scores them; everything else
(built-in scenes included) on black; the choice printed once and kept in metrics.json."""

import json
import os

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax import cli
from nerf_jax.data import loaders, scenes
from nerf_jax.data.export import export_blender
from tests.helpers import load_data, small_config

LINE = ("background: white, the convention of Blender (NeRF-synthetic) data "
        "(data.background='auto')")


def _blender(tmp_path, rgb_only=False):
  """(folder, truth): the 'diffuse' scene as a Blender folder (alpha = opacity), 8 views of 12 x
  12 (views 6, 7 the test split); with rgb_only its PNGs lose the alpha channel."""
  truth = scenes.make_dataset("diffuse", num_views=8, height=12, width=12)
  folder = str(tmp_path / ("rgb" if rgb_only else "rgba"))
  export_blender(truth, folder, split_at=6, background=truth.background)
  if rgb_only:
    for split in ("train", "test"):
      for name in os.listdir(os.path.join(folder, split)):
        path = os.path.join(folder, split, name)
        iio.imwrite(path, iio.imread(path)[..., :3])
  return folder, truth


def test_blender_rgba_loads_on_white_under_auto_and_black_when_asked(tmp_path):
  folder, truth = _blender(tmp_path)
  assert loaders.DataSettings().background == "auto"
  train, _ = load_data({"path": folder})
  assert train.background == (1.0, 1.0, 1.0)
  # The truth's emission re-composited on white by hand: rgb + (1 - acc) (white - old).
  on_white = truth.images + (1 - truth.accs[..., None]) * (1.0 - np.asarray(truth.background))
  np.testing.assert_allclose(train.images, on_white[:6], atol=1.5 / 255)
  train, _ = load_data({"path": folder, "background": "black"})
  assert train.background == (0.0, 0.0, 0.0)
  np.testing.assert_allclose(train.images, truth.images[:6], atol=1.5 / 255)
  train, _ = load_data({"path": folder, "background": [0.2, 0.4, 0.6]})
  np.testing.assert_allclose(train.background, (0.2, 0.4, 0.6), rtol=1e-6)


def test_everything_else_is_black_under_auto(tmp_path):
  folder, _ = _blender(tmp_path, rgb_only=True)  # RGB photos: no opacity to composite
  assert loaders.auto_background(folder)[0] == "black"
  assert load_data({"path": folder})[0].background == (0.0, 0.0, 0.0)
  for scene in ("diffuse", "white"):  # built-in scenes: black, whatever they were rendered on
    assert loaders.auto_background("")[0] == "black"
    assert loaders.is_auto(small_config(**{"data.scene": scene}).data.background)


def _train(config, workdir, capsys):
  """(metrics.json, config.json's data section, the lines printed) of a 1-step run."""
  cli.train(config, str(workdir))
  out = capsys.readouterr().out.splitlines()
  metrics = json.loads((workdir / "metrics.json").read_text())
  saved = json.loads((workdir / "config.json").read_text())["data"]
  return metrics, saved, out


@pytest.mark.slow  # trains three 1-step runs
def test_a_run_records_the_background_it_was_scored_on(tmp_path, capsys):
  folder, _ = _blender(tmp_path)
  metrics, saved, out = _train(small_config(**{"data.path": folder, "train.max_steps": 1}),
                               tmp_path / "blender", capsys)
  assert metrics["background"] == "white" and saved["background"] == "white"
  assert out.count(LINE) == 1
  metrics, saved, out = _train(small_config(**{"data.scene": "diffuse", "data.num_views": 5,
                                               "data.holdout_from": 4, "data.image_size": 8,
                                               "train.max_steps": 1}),
                               tmp_path / "builtin", capsys)
  assert metrics["background"] == "black" and saved["background"] == "black"
  assert [l for l in out if l.startswith("background:")] == [
      "background: black, the convention of data other than Blender's RGBA folders "
      "(data.background='auto')"]
  metrics, _, out = _train(small_config(**{"data.path": folder, "train.max_steps": 1,
                                           "data.background": "black"}),
                           tmp_path / "asked", capsys)
  assert metrics["background"] == "black"
  assert not [l for l in out if l.startswith("background:")]
