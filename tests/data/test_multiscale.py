"""Tests of nerf_jax.data.multiscale (the converter to mip-NeRF's multiscale format) and
nerf_jax.data.multicam (its reader and writer): the levels against a box filter written here,
the metadata, the loader round trip, and the exporters' refusal of per-image cameras."""

import json
import math

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.data import export, multicam, multiscale, scenes
from nerf_jax.data.dataset import DataError
from tests.helpers import assert_data_error, load_data

LEVELS = 3
SIZE = 16


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
  """(blender folder, multiscale folder): 5 views of the built-in 'fog' scene (alpha = opacity)
  and their conversion."""
  root = tmp_path_factory.mktemp("multiscale")
  fog = scenes.make_dataset("fog", num_views=5, height=SIZE, width=SIZE, focal=22.2)
  blender, out = str(root / "blender"), str(root / "ms")
  export.export_blender(fog, blender, split_at=3, background=fog.background)
  assert multiscale.main([f"--blender={blender}", f"--out={out}", f"--levels={LEVELS}"]) == 0
  return blender, out


def _box_levels(rgba):
  """Each level a loop's mean of the 2×2 block above it, float64."""
  levels = [rgba]
  for _ in range(LEVELS - 1):
    above = levels[-1]
    h, w = above.shape[0] // 2, above.shape[1] // 2
    level = np.zeros((h, w, 4))
    for r in range(h):
      for c in range(w):
        level[r, c] = (above[2 * r, 2 * c] + above[2 * r + 1, 2 * c] + above[2 * r, 2 * c + 1] +
                       above[2 * r + 1, 2 * c + 1]) / 4
    levels.append(level)
  return levels


def test_levels_are_box_means_of_the_straight_rgba_and_the_metadata_says_so(folders):
  blender, out = folders
  meta = json.load(open(f"{out}/metadata.json"))
  source = json.load(open(f"{blender}/transforms_train.json"))
  focal = 0.5 * SIZE / math.tan(0.5 * source["camera_angle_x"])
  train = meta["train"]
  assert set(train) == set(multicam.FIELDS) and len(train["file_path"]) == 3 * LEVELS
  for v, frame in enumerate(source["frames"]):
    rgba = iio.imread(f"{blender}/{frame['file_path']}.png").astype(np.float64) / 255
    for j, want in enumerate(_box_levels(rgba)):
      k = v * LEVELS + j
      assert train["file_path"][k].startswith("images_train/")
      got = iio.imread(f"{out}/{train['file_path'][k]}").astype(np.float64) / 255
      np.testing.assert_allclose(got, want, atol=0.5 / 255 + 1e-9)  # 8-bit, rounded
      assert (train["width"][k], train["height"][k]) == (SIZE >> j, SIZE >> j)
      np.testing.assert_allclose(train["focal"][k], focal / 2 ** j, rtol=1e-12)
      assert train["lossmult"][k] == 4 ** j and train["label"][k] == j
      assert train["cam2world"][k] == frame["transform_matrix"]
      w, f = SIZE >> j, focal / 2 ** j
      np.testing.assert_allclose(train["pix2cam"][k], [[1 / f, 0, -w / 2 / f],
                                                       [0, -1 / f, w / 2 / f], [0, 0, -1]])
  assert len(meta["test"]["file_path"]) == len(meta["val"]["file_path"]) == 2 * LEVELS


def test_the_loader_gives_back_the_images_cameras_lossmults_and_labels(folders):
  _, out = folders
  meta = json.load(open(f"{out}/metadata.json"))["test"]
  train, test = load_data({"path": out, "background": "white"})
  assert (len(train), len(test)) == (3 * LEVELS, 2 * LEVELS) and test.mixed_sizes
  for k, name in enumerate(meta["file_path"]):
    rgba = iio.imread(f"{out}/{name}").astype(np.float64) / 255
    want = rgba[..., :3] * rgba[..., 3:] + (1 - rgba[..., 3:])
    np.testing.assert_allclose(test.image(k), want, atol=1e-6)
    np.testing.assert_allclose(test.acc(k), rgba[..., 3], atol=1e-6)
    height, width, (fx, fy, cx, cy) = test.cameras.camera(k)
    assert (height, width) == (meta["height"][k], meta["width"][k])
    np.testing.assert_allclose([fx, fy, cx, cy], [meta["focal"][k]] * 2 + [width / 2] * 2)
    np.testing.assert_array_equal(test.poses[k], np.float32(meta["cam2world"][k]))
  np.testing.assert_array_equal(test.lossmult, meta["lossmult"])
  assert list(test.labels) == [str(v) for v in meta["label"]]
  assert test.pixel_center == 0.5 and (test.near, test.far) == (meta["near"][0], meta["far"][0])


def test_one_level_is_one_camera(folders, tmp_path):
  blender, _ = folders
  multiscale.convert(blender, str(tmp_path), levels=1)
  train = multicam.load(str(tmp_path), split="train")
  assert not train.mixed_sizes and train.image_cameras is None
  assert train.images.shape == (3, SIZE, SIZE, 3)


def test_exporters_refuse_per_image_cameras_in_one_line(folders, tmp_path):
  train, _ = load_data({"path": folders[1]})
  for write in (lambda: export.export_npz(train, str(tmp_path / "a.npz")),
                lambda: export.export_blender(train, str(tmp_path / "b")),
                lambda: export.export_llff(train, str(tmp_path / "c"))):
    assert_data_error(["cameras of their own", "--format=multiscale"], write)


def test_the_multiscale_export_round_trips_per_image_cameras(tmp_path):
  ds = scenes.make_dataset("multiscale", num_views=5, height=16, width=16)  # as the CLI makes it
  assert export.main(["--scene=multiscale", "--format=multiscale", f"--out={tmp_path}",
                      "--num_views=5", "--image_size=16"]) == 0
  train, test = load_data({"path": str(tmp_path)})
  assert (len(train), len(test)) == (4, 1)
  for k in range(5):
    back = train if k < 4 else test
    i = k if k < 4 else 0
    assert back.cameras.camera(i)[:2] == ds.cameras.camera(k)[:2]
    np.testing.assert_allclose(back.image(i), ds.image(k), atol=0.5 / 255 + 1e-6)
    np.testing.assert_allclose(back.cameras.camera(i)[2], ds.cameras.camera(k)[2], rtol=1e-6)
  np.testing.assert_array_equal(train.lossmult, ds.lossmult[:4])
  assert list(train.labels) == list(ds.labels[:4])


def test_metadata_that_disagree_with_the_images_are_named(folders, tmp_path):
  _, out = folders
  meta = json.load(open(f"{out}/metadata.json"))
  meta["train"]["width"][1] = 99
  (tmp_path / "metadata.json").write_text(json.dumps(meta))
  (tmp_path / "images_train").symlink_to(f"{out}/images_train")
  assert_data_error(["metadata.json: train", "metadata says 99x8"], multicam.load, str(tmp_path))
  meta["train"]["width"][1], meta["train"]["lossmult"] = 8, [1.0]
  (tmp_path / "metadata.json").write_text(json.dumps(meta))
  assert_data_error(["'lossmult' must be a list of 9"], multicam.load, str(tmp_path))
  with pytest.raises(DataError, match="no transforms"):
    multiscale.convert(str(tmp_path), str(tmp_path / "x"))
