"""Tests of the Dataset, the loaders and the exporters."""

import os
import tracemalloc

import imageio.v3 as iio
import ml_collections
import numpy as np
import pytest

from nerf_jax.data import scenes
from nerf_jax.data import export, load_blender, load_npz
from tests.helpers import assert_data_error as _error, blender_folder as _blender
from tests.helpers import load_data, small_config

Q = 1.0 / 255 + 1e-6  # 8-bit quantisation


@pytest.fixture(scope="module")
def fog():
  return scenes.make_dataset("fog", num_views=6, height=16, width=16, focal=22.2)


# The data section the loaders read: 10 views of 20² of the built-in diffuse scene, the
# reference's 80/20 split, pixel corners.
DATA = {"data.path": "", "data.scene": "diffuse", "data.holdout_from": -1, "data.num_views": 10,
        "data.image_size": 20, "data.pixel_center": 0.0, "data.background": "black",
        "data.half_res": False}


def test_npz_round_trip(fog, tmp_path):
  path = str(tmp_path / "fog.npz")
  export.export_npz(fog, path)
  back = load_npz(path)
  for key in ("images", "poses", "depths", "accs"):
    np.testing.assert_array_equal(getattr(back, key), getattr(fog, key))
  assert back.intrinsics == fog.intrinsics and (back.near, back.far) == (2.0, 6.0)
  assert back.background == (0.0, 0.0, 0.0)


def test_npz_round_trip_keeps_the_background(tmp_path):
  white = scenes.make_dataset("white", num_views=2, height=8, width=8, focal=11.1)
  export.export_npz(white, str(tmp_path / "w.npz"))
  back = load_npz(str(tmp_path / "w.npz"))
  assert back.background == (1.0, 1.0, 1.0)
  np.testing.assert_array_equal(back.accs, white.accs)


def test_rgb_only_npz_is_the_reference_format(tmp_path):
  white = scenes.make_dataset("white", num_views=2, height=8, width=8,
                              focal=scenes.TINY_NERF_FOCAL * 8 / 100)  # as the CLI's 8 px
  path = str(tmp_path / "w.npz")
  assert export.main(["--scene=white", "--format=npz", "--num_views=2", "--image_size=8",
                      "--rgb_only", f"--out={path}"]) == 0
  assert sorted(np.load(path).keys()) == ["focal", "images", "poses"]
  back = load_npz(path)
  np.testing.assert_array_equal(back.images, white.images)
  assert back.accs is None and (back.near, back.far) == (2.0, 6.0)


def test_blender_round_trip(fog, tmp_path):
  export.export_blender(fog, str(tmp_path), split_at=4)
  train, test = (load_blender(str(tmp_path), "white", split=s) for s in ("train", "test"))
  assert (len(train), len(test)) == (4, 2)
  np.testing.assert_allclose(train.images, fog.images[:4], atol=Q)  # opaque: any background
  np.testing.assert_allclose(test.images, fog.images[4:], atol=Q)
  np.testing.assert_array_equal(test.poses, fog.poses[4:])
  np.testing.assert_allclose(train.intrinsics, fog.intrinsics, rtol=1e-6)
  assert len(load_blender(str(tmp_path), split="val")) == 2


def test_blender_alpha_export_recomposites(fog, tmp_path):
  export.export_blender(fog, str(tmp_path), background=(0.0, 0.0, 0.0))
  train, _ = fog.split(-1)
  np.testing.assert_allclose(load_blender(str(tmp_path)).images, train.images, atol=Q)
  on_white = load_blender(str(tmp_path), background="white")
  np.testing.assert_allclose(on_white.images, train.images + (1 - train.accs[..., None]),
                             atol=2 * Q)
  assert on_white.background == (1.0, 1.0, 1.0)
  np.testing.assert_allclose(on_white.accs, train.accs, atol=Q / 2)  # the 8-bit alpha channel
  on_black = load_blender(str(tmp_path))
  assert on_black.background == (0.0, 0.0, 0.0)
  recomposited = on_black.images + (1 - on_black.accs[..., None]) * (
      np.float32(1.0) - np.asarray(on_black.background, np.float32))  # Dataset's documented rule
  np.testing.assert_allclose(recomposited, on_white.images, atol=1e-6)


def test_blender_loading_peaks_near_the_size_of_what_it_returns(tmp_path):
  """800 x 800 NeRF-synthetic folders must load in little more than their float32 arrays: the
  frames are converted one at a time (stacking float64 copies of all of them peaked at ~9x)."""
  views = scenes.make_dataset("diffuse", num_views=14, height=48, width=48, focal=66.6)
  export.export_blender(views, str(tmp_path), split_at=12)  # 12 training views
  tracemalloc.start()  # numpy reports its buffers to tracemalloc
  try:
    dataset = load_blender(str(tmp_path))
    peak = tracemalloc.get_traced_memory()[1]
  finally:
    tracemalloc.stop()
  returned = dataset.images.nbytes + dataset.accs.nbytes
  assert returned == 12 * 48 * 48 * 4 * 4
  frame_float64 = 48 * 48 * 4 * 8  # one decoded RGBA frame
  # Beyond the returned arrays: a few float64 copies of one frame, not of all twelve.
  assert peak - returned < 6 * frame_float64, (peak, returned)


def test_opaque_blender_export_has_unit_accs(fog, tmp_path):
  export.export_blender(fog, str(tmp_path), split_at=4)
  np.testing.assert_array_equal(load_blender(str(tmp_path)).accs, 1.0)


def test_load_dataset_builtin():
  train, test = load_data(small_config(DATA).data)
  assert (len(train), len(test)) == (8, 2) and train.images.shape == (8, 20, 20, 3)
  assert train.focal == pytest.approx(scenes.TINY_NERF_FOCAL / 5)
  assert train.accs is not None and train.depths.shape == (8, 20, 20)


def test_load_dataset_npz_and_blender(fog, tmp_path):
  export.export_npz(fog, str(tmp_path / "fog.npz"))
  train, test = load_data(small_config(
      {**DATA, "data.path": str(tmp_path / "fog.npz"), "data.holdout_from": 4}).data)
  np.testing.assert_array_equal(test.images, fog.images[4:])
  np.testing.assert_array_equal(train.poses, fog.poses[:4])
  export.export_blender(fog, str(tmp_path / "blender"), split_at=5)
  train, test = load_data(small_config(
      {**DATA, "data.path": str(tmp_path / "blender"), "data.half_res": True}).data)
  assert (len(train), len(test)) == (5, 1) and train.images.shape == (5, 8, 8, 3)
  assert train.focal == pytest.approx(fog.focal / 2)


def test_missing_config_fields_use_defaults():
  train, test = load_data(ml_collections.ConfigDict({"num_views": 5, "image_size": 8}))
  assert (len(train), len(test)) == (4, 1)


def test_split_semantics(fog):
  train, test = fog.split(-1)
  assert (len(train), len(test)) == (4, 2)  # int(0.8 * 6)
  train, test = fog.split(5)
  np.testing.assert_array_equal(test.images, fog.images[5:])
  np.testing.assert_array_equal(train.accs, fog.accs[:5])
  for bad in (0, 6, -2):
    _error([f"holdout_from={bad}"], fog.split, bad)


def _npz(tmp_path, **arrays):
  base = {"images": np.zeros((2, 4, 4, 3), np.float32), "poses": np.tile(np.eye(4), (2, 1, 1)),
          "focal": np.float64(5.0)}
  base.update(arrays)
  path = str(tmp_path / "bad.npz")
  np.savez(path, **{k: v for k, v in base.items() if v is not None})
  return path


def test_npz_errors(tmp_path):
  _error(["nope.npz", "no such"], load_data,
         small_config({**DATA, "data.path": str(tmp_path / "nope.npz")}).data)
  _error(["'focal'", "has: images, poses"], load_npz, _npz(tmp_path, focal=None))
  _error(["'poses' has 3", "2 views"], load_npz, _npz(tmp_path, poses=np.zeros((3, 4, 4))))
  nan = np.zeros((2, 4, 4, 3))
  nan[0, 1, 1, 1] = np.nan
  _error(["bad.npz", "'images'", "NaN"], load_npz, _npz(tmp_path, images=nan))
  _error(["bad.npz", "'images'", "expected [0, 1]"], load_npz,
         _npz(tmp_path, images=np.full_like(nan, 255.0)))
  _error(["bad.npz", "'poses'", "(2, 3, 3)"], load_npz, _npz(tmp_path, poses=np.zeros((2, 3, 3))))
  _error(["bad.npz", "'images'", "channels"], load_npz,
         _npz(tmp_path, images=np.zeros((2, 4, 4, 2))))
  (tmp_path / "notes.txt").write_text("hi")
  _error(["unknown dataset format", "notes.txt"], load_data,
         small_config({**DATA, "data.path": str(tmp_path / "notes.txt")}).data)
  _error(["unknown dataset format"], load_data,
         small_config({**DATA, "data.path": str(tmp_path)}).data)
  _error(["data.scene", "'lego'"], load_data, small_config({**DATA, "data.scene": "lego"}).data)
  _error(["background"], load_data,
         small_config({**DATA, "data.path": _npz(tmp_path), "data.background": "pink"}).data)


def test_npz_uint8_rgba_composited_on_white(tmp_path):
  rgba = np.zeros((2, 4, 4, 4), np.uint8)
  rgba[:, :2, :, 0] = 255
  rgba[:, :2, :, 3] = 255  # top half opaque red; bottom half transparent
  ds = load_npz(_npz(tmp_path, images=rgba, poses=np.zeros((2, 3, 4))), background="white")
  np.testing.assert_array_equal(ds.images[:, :2], np.broadcast_to([1.0, 0, 0], (2, 2, 4, 3)))
  np.testing.assert_array_equal(ds.images[:, 2:], 1.0)
  assert ds.poses.shape == (2, 4, 4) and np.all(ds.poses[:, 3] == [0, 0, 0, 1])
  np.testing.assert_array_equal(ds.accs[:, :2], 1.0)
  np.testing.assert_array_equal(ds.accs[:, 2:], 0.0)
  assert ds.background == (1.0, 1.0, 1.0)
  rgb = load_npz(_npz(tmp_path))
  assert rgb.accs is None and rgb.background == (0.0, 0.0, 0.0)  # unknown


def test_blender_errors(tmp_path):
  meta = str(tmp_path / "transforms_train.json")
  _error([meta, "line 2 column 1"], load_blender, _blender(tmp_path, text='{"frames":\n'))
  _error([meta, "'camera_angle_x'"], load_blender, _blender(tmp_path, {"camera_angle_x": None}))
  missing = {"frames": [{"file_path": "./r_9.png", "transform_matrix": np.eye(4).tolist()}]}
  _error([meta, "frames[0].file_path", "r_9.png", "not found"], load_blender,
         _blender(tmp_path, missing))
  _error([meta, "frames[0]", "'transform_matrix'"], load_blender,
         _blender(tmp_path, {"frames": [{"file_path": "r_0.png"}]}))
  _error([meta, "frames[0].transform_matrix"], load_blender,
         _blender(tmp_path, {"frames": [{"file_path": "r_0", "transform_matrix": [[1, 2]]}]}))
  _error(["transforms_test.json", "no such"], load_blender, _blender(tmp_path), split="test")
  iio.imwrite(tmp_path / "r_1.png", np.zeros((6, 6, 4), np.uint8))
  two = {"frames": [{"file_path": f"./r_{k}", "transform_matrix": np.eye(4).tolist()}
                    for k in range(2)]}
  _error([meta, "different sizes"], load_blender, _blender(tmp_path, two))


def test_blender_rgba_on_white_and_half_res(tmp_path):
  image = np.zeros((4, 6, 4), np.uint8)
  image[:2, :2] = [255, 0, 0, 255]  # opaque red block -> red after 2x2 averaging
  image[2:, :2, 3] = 0  # transparent -> background
  image[:, 2:4] = [255, 0, 0, 51]  # 20% red over white -> (1, 0.8, 0.8)
  image[0, 4], image[1, 5] = [0, 0, 255, 255], [0, 0, 255, 255]  # half-covered blue block
  path = _blender(tmp_path, image=image)
  full = load_blender(path, background="white")
  np.testing.assert_allclose(full.images[0, 0, 2], [1.0, 0.8, 0.8], atol=1e-6)
  np.testing.assert_array_equal(full.images[0, 3, 0], 1.0)
  half = load_blender(path, background="white", half_res=True)
  assert half.images.shape == (1, 2, 3, 3) and half.focal == pytest.approx(full.focal / 2)
  np.testing.assert_allclose(half.images[0, :, 0], [[1, 0, 0], [1, 1, 1]], atol=1e-6)
  np.testing.assert_allclose(half.images[0, 0, 1], [1.0, 0.8, 0.8], atol=1e-6)
  np.testing.assert_allclose(half.images[0, 0, 2], [0.5, 0.5, 1.0], atol=1e-6)  # no dark fringe
  np.testing.assert_allclose(half.accs[0], [[1.0, 0.2, 0.5], [0.0, 0.2, 0.0]], atol=1e-6)
  assert half.accs.dtype == np.float32 and half.background == (1.0, 1.0, 1.0)


def test_export_cli(tmp_path):
  out = str(tmp_path / "w.npz")
  assert export.main(["--scene=white", "--format=npz", f"--out={out}", "--num_views=3",
                      "--image_size=8"]) == 0
  assert load_npz(out).images.shape == (3, 8, 8, 3)
  assert export.main(["--scene=lego", "--format=npz", f"--out={out}"]) == 1
  assert not os.path.exists(tmp_path / "x")


def test_blender_focal_comes_from_camera_angle_x_and_the_width(tmp_path):
  """NeRF-synthetic's 800-pixel-wide frames at camera_angle_x = 0.6911112 have focal 1111.11;
  a non-square frame (2 rows) shows the width, not the height, sets it."""
  folder = _blender(tmp_path, {"camera_angle_x": 0.6911112}, image=np.zeros((2, 800, 4), np.uint8))
  train = load_blender(folder)
  fx, fy, cx, cy = train.intrinsics
  assert fx == fy == pytest.approx(1111.11, abs=0.01)
  assert (cx, cy) == (400.0, 1.0) and (train.height, train.width) == (2, 800)
