"""--config=auto's data.factor: decided from the photos' headers before they are loaded, for LLFF
and transforms.json folders, unless the user set one. The photos here are written by the test:
the built-in `forward` scene exported as LLFF at 24 px, with MAX_SIDE patched small, and a 12 MP
transforms.json folder whose one frame is a blank JPEG (only its header is read)."""

import json

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.data.llff import export_llff
from nerf_jax.run import config_lib, experiment
from nerf_jax.run.auto import resolution
from tests.helpers import load_data


def _llff(tmp_path):
  """An LLFF folder of the built-in `forward` scene: 12 photos of 24 x 24 px."""
  config = config_lib.load("debug")
  config.data.scene, config.data.image_size, config.data.num_views = "forward", 24, 12
  train, _ = load_data(config.data)
  export_llff(train, str(tmp_path))
  return str(tmp_path)


def _auto(path, flags=None):
  """configs/auto.py on `path` with `flags` ({field: value}) as given on the command line."""
  config = config_lib.load("auto")
  config.data.path = path
  for name, value in (flags or {}).items():
    config_lib.set_field(config, name, value)
  config.auto_flags = tuple(["data.path", *(flags or {})])
  return config


@pytest.mark.parametrize("side, factor", [(4032, 4), (1024, 1), (1025, 2), (3000, 3)])
def test_the_smallest_integer_factor_within_the_side(side, factor):
  # ceil(side / 1024), written out: the largest f with side // (f - 1) > 1024.
  assert resolution.factor_for(side, 10, 1024) == factor
  assert side // factor <= 1024 and (factor == 1 or side // (factor - 1) > 1024)


def test_a_twelve_megapixel_folder_gets_factor_four_on_a_cpu(tmp_path):
  iio.imwrite(tmp_path / "frame.jpg", np.zeros((3024, 4032, 3), np.uint8))
  (tmp_path / "transforms.json").write_text(json.dumps(
      {"frames": [{"file_path": "frame.jpg", "transform_matrix": np.eye(4).tolist()}]}))
  effects, lines = resolution.factor_effects(_auto(str(tmp_path)), "cpu")
  assert effects == {"data.factor": 4}
  assert lines == ["data.factor=4: the photos are 4032 x 3024 (12.2 MP); the smallest integer "
                   "factor that brings them to 1008 x 756 (> 1024 px a side on the cpu backend "
                   "(MAX_SIDE) at full size)"]
  assert resolution.factor_effects(_auto(str(tmp_path)), "gpu")[0] == {"data.factor": 2}


def test_setup_loads_an_llff_folder_at_the_factor_and_records_why(tmp_path, monkeypatch,
                                                                   capsys):
  monkeypatch.setitem(resolution.MAX_SIDE, "cpu", 10)  # 24 px photos: ceil(24 / 10) = 3
  monkeypatch.setattr(experiment.jax, "default_backend", lambda: "cpu")
  exp = experiment.setup(_auto(_llff(tmp_path)))
  assert exp.config.data.factor == 3
  assert (exp.train_ds.height, exp.train_ds.width) == (8, 8)  # 24 // 3
  line = ("data.factor=3: the photos are 24 x 24 (0.000576 MP); the smallest integer factor that "
          "brings them to 8 x 8 (> 10 px a side on the cpu backend (MAX_SIDE) at full size)")
  assert exp.config.auto_decisions[0] == line
  assert f"auto: {line}" in capsys.readouterr().out


def test_your_factor_wins(tmp_path, monkeypatch, capsys):
  monkeypatch.setitem(resolution.MAX_SIDE, "cpu", 10)
  monkeypatch.setattr(experiment.jax, "default_backend", lambda: "cpu")
  exp = experiment.setup(_auto(_llff(tmp_path), {"data.factor": 2}))
  assert exp.config.data.factor == 2
  assert (exp.train_ds.height, exp.train_ds.width) == (12, 12)
  assert exp.config.auto_decisions[0] == ("data.factor=2 from your flags, not auto's 3 (the "
                                          "photos are 24 x 24 (0.000576 MP))")
  # Given on the command line as 1, the default, it wins too.
  effects, lines = resolution.factor_effects(_auto(_llff(tmp_path), {"data.factor": 1}), "cpu")
  assert (effects, lines) == ({}, ["data.factor=1 from your flags, not auto's 3 (the photos "
                                   "are 24 x 24 (0.000576 MP))"])


def test_small_photos_stay_at_full_size_and_other_data_is_not_measured(tmp_path):
  effects, lines = resolution.factor_effects(_auto(_llff(tmp_path)), "cpu")
  assert effects == {"data.factor": 1}
  assert lines == ["data.factor=1: the photos are 24 x 24 (0.000576 MP), full size (<= 1024 px a "
                   "side on the cpu backend (MAX_SIDE))"]
  assert resolution.factor_effects(_auto(""), "cpu") == ({}, [])  # a built-in scene
