"""docs/extending.md's data-format walk-through, run as written: its format module and its config
file are copied from the doc into a temporary folder (no file of the tree is touched), a
built-in scene is written as a rig's folder, read back through data.path by the library's
loader as the config file leaves it, and trained a few steps on."""

import json
import sys

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.data import formats, loaders
from nerf_jax.run import config_lib, experiment, train_lib
from tests import helpers
from tests.helpers import TINY_GRID

THIS = "tests/topics/test_extending_format.py"
# The built-in scene written as a rig's folder: 6 views of 16 px, the last one held out.
SCENE = {"data.scene": "diffuse", "data.num_views": 6, "data.image_size": 16,
         "data.holdout_from": 5}
FLIP_Y_Z = np.diag([1.0, -1.0, -1.0, 1.0])  # nerf_jax's camera axes <-> OpenCV's


@pytest.fixture
def config_file(tmp_path, monkeypatch):
  """The path of the doc's config file, its format module a package beside it on sys.path; the
  format it registers is forgotten afterwards."""
  path = helpers.write_walkthrough(tmp_path, THIS, "my_formats/rig.py")
  monkeypatch.syspath_prepend(str(tmp_path))
  yield path
  formats.unregister("rig")
  for name in [n for n in sys.modules if n == "my_formats" or n.startswith("my_formats.")]:
    del sys.modules[name]


def write_rig(scene_split, folder):
  """Write the (train, test) Datasets `scene_split` as a rig's folder (the doc's rig.json: OpenCV
  camera axes, 8-bit PNGs); returns its path."""
  folder.mkdir()
  photos = []
  for held_out, dataset in enumerate(scene_split):
    for k, (image, pose) in enumerate(zip(dataset.images, dataset.poses)):
      name = f"{'test' if held_out else 'train'}_{k}.png"
      iio.imwrite(folder / name, np.round(np.asarray(image) * 255).astype(np.uint8))
      photos.append({"file": name, "test": bool(held_out),
                     "camera_to_world": (np.asarray(pose, np.float64) @ FLIP_Y_Z).tolist()})
  train = scene_split[0]
  (folder / "rig.json").write_text(json.dumps({"focal": float(train.intrinsics[0]),
                                               "near": train.near, "far": train.far,
                                               "photos": photos}))
  return str(folder)


@pytest.fixture
def scene_and_rig(tmp_path):
  """((train, test) of the built-in scene, the path of its rig folder)."""
  scene = helpers.load_data(helpers.small_config(SCENE).data)
  return scene, write_rig(scene, tmp_path / "rig")


def test_the_docs_format_reads_a_rig_folder_as_the_scene_it_was_written_from(config_file,
                                                                              scene_and_rig):
  scene, rig = scene_and_rig
  config = config_lib.load(config_file)  # registers the format, as a run of the file does
  assert formats.names()[-2:] == ("rig", "colmap")  # tried before COLMAP's folders
  assert formats.detect(rig).name == "rig" and loaders.auto_background(rig)[0] == "black"
  assert formats.photo_paths(rig) is None  # it names no photos for data.factor
  config.data.path = rig
  loaded = helpers.load_data(config.data)
  for ours, truth in zip(loaded, scene):
    assert len(ours) == len(truth) and ours.images.dtype == np.float32
    np.testing.assert_allclose(ours.images, truth.images, atol=0.5 / 255 + 1e-6)  # 8-bit PNGs
    np.testing.assert_allclose(ours.poses, truth.poses, atol=1e-6)  # the axes flipped back
    np.testing.assert_allclose(ours.intrinsics, truth.intrinsics, rtol=1e-6)
    assert (ours.near, ours.far, ours.background) == (truth.near, truth.far, (0.0, 0.0, 0.0))
  assert (len(loaded[0]), len(loaded[1])) == (5, 1)


def test_the_docs_format_names_what_is_wrong_and_is_named_for_unknown_data(config_file,
                                                                           scene_and_rig,
                                                                           tmp_path):
  _, rig = scene_and_rig
  config = config_lib.load(config_file)
  meta_path = tmp_path / "rig" / "rig.json"
  meta = json.loads(meta_path.read_text())
  for photo in meta["photos"]:
    photo["test"] = False
  meta_path.write_text(json.dumps(meta))
  config.data.path = rig
  with pytest.raises(loaders.DataError, match=r"rig\.json: needs training photos and held-out"):
    helpers.load_data(config.data)
  (tmp_path / "other").mkdir()
  config.data.path = str(tmp_path / "other")
  with pytest.raises(loaders.DataError, match=r"poses_bounds\.npy, rig\.json or a COLMAP model"):
    helpers.load_data(config.data)


def test_the_docs_format_trains_from_its_config_file(config_file, scene_and_rig, tmp_path):
  _, rig = scene_and_rig
  steps = {**TINY_GRID, "train.max_steps": 6, "train.log_every": 3,
           "train.checkpoint_every": 6, "data.path": rig}
  config = helpers.small_config(steps, base=config_file)
  assert config.data.background == "black"  # the doc's config file, as loaded
  workdir = str(tmp_path / "run")
  train_lib.train_and_evaluate(config, workdir)
  exp, state = experiment.restore(workdir)  # this process knows the format: it is registered
  assert int(state.step) == 6 and (len(exp.train_ds), len(exp.test_ds)) == (5, 1)
  records = [json.loads(line) for line in open(f"{workdir}/metrics.jsonl")]
  assert [r["step"] for r in records if "loss" in r] == [3, 6]
  assert all(np.isfinite(r["loss"]) for r in records if "loss" in r)
