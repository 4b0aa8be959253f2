"""Masks (nerf_jax.data.masks, Dataset.masks): read as nerfstudio, instant-ngp, LLFF and COLMAP
users store them, made smaller with their images without leaking masked pixels, carried by
subsets, written by every exporter and read back the same, and bad masks in one line."""

import dataclasses
import json
import os

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.data import export, loaders, masks, nerfstudio, process, scenes, sfm
from nerf_jax.data.scenes import capture as capture_scene
from nerf_jax.data.dataset import DataError, Dataset
from nerf_jax.data.llff import export_llff, load_llff
from tests.helpers import assert_data_error

SIZE = 8  # pixels a side of the tiny test images


def _random_masks(num, height, width, seed=0):
  """float32 [num, height, width] of 0 and 1, about a third masked, none all masked."""
  rng = np.random.default_rng(seed)
  out = (rng.random((num, height, width)) > 0.35).astype(np.float32)
  out[:, 0, 0] = 1.0
  return out


@pytest.fixture(scope="module")
def scene():
  """A built-in scene of 5 views of 16 px with random masks."""
  ds = scenes.make_dataset("white", num_views=5, height=16, width=16)
  return dataclasses.replace(ds, masks=_random_masks(5, 16, 16))


def _ngp_folder(tmp_path, mask_fields=None, dynamic=None, size=SIZE):
  """A transforms.json folder of 2 frames of `size` px; mask_fields: each frame's extra fields;
  dynamic: {frame: uint8 [H, W]} written as instant-ngp's dynamic_mask_f_<k>.png."""
  (tmp_path / "images").mkdir(exist_ok=True)
  frames = []
  for k in range(2):
    iio.imwrite(tmp_path / f"images/f_{k}.png", np.full((size, size, 3), 100 + k, np.uint8))
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, 3.0 + k]
    frames.append({"file_path": f"images/f_{k}.png", "transform_matrix": pose.tolist(),
                   **((mask_fields or {}).get(k, {}))})
  for k, mask in (dynamic or {}).items():
    iio.imwrite(tmp_path / f"images/dynamic_mask_f_{k}.png", mask)
  meta = {"nerf_jax_normalized": True, "near": 1.0, "far": 8.0, "fl_x": 10.0,
          "frames": frames}
  (tmp_path / "transforms.json").write_text(json.dumps(meta))
  return str(tmp_path)


def test_nerfstudio_mask_path_zero_means_ignore(tmp_path):
  mask = np.full((SIZE, SIZE), 255, np.uint8)
  mask[2:4, 5] = 0
  (tmp_path / "masks").mkdir()
  iio.imwrite(tmp_path / "masks/m0.png", mask)
  folder = _ngp_folder(tmp_path, {0: {"mask_path": "masks/m0.png"}})
  ds, names, _ = nerfstudio.load(folder)
  assert names == ["images/f_0.png", "images/f_1.png"]
  np.testing.assert_array_equal(ds.masks[0], mask > 0)
  np.testing.assert_array_equal(ds.masks[1], 1.0)  # a frame without a mask keeps every pixel


def test_without_masks_the_dataset_has_none(tmp_path):
  assert nerfstudio.load(_ngp_folder(tmp_path))[0].masks is None


def test_instant_ngp_dynamic_mask_nonzero_means_ignore(tmp_path):
  dynamic = np.zeros((SIZE, SIZE), np.uint8)
  dynamic[5:, :3] = 1  # any non-zero value is dynamic
  ds = nerfstudio.load(_ngp_folder(tmp_path, dynamic={1: dynamic}))[0]
  np.testing.assert_array_equal(ds.masks[1], dynamic == 0)
  np.testing.assert_array_equal(ds.masks[0], 1.0)


def test_a_pixel_is_kept_only_if_its_whole_footprint_is(tmp_path):
  """factor 2: a 2 x 2 block with one masked pixel is masked (a min pool), nothing leaks."""
  dynamic = np.zeros((SIZE, SIZE), np.uint8)
  dynamic[3, 3] = 255  # one pixel of block (1, 1)
  ds = nerfstudio.load(_ngp_folder(tmp_path, dynamic={0: dynamic}), factor=2)[0]
  want = np.ones((SIZE // 2, SIZE // 2), np.float32)
  want[1, 1] = 0.0
  np.testing.assert_array_equal(ds.masks[0], want)
  assert masks.downscale(np.array([[1, 1, 0], [1, 1, 1]], np.float32), 2).tolist() == [[1.0]]


def test_a_resampled_mask_keeps_no_masked_neighbour():
  """A mask resampled through a lens keeps a pixel only where every bilinear neighbour is kept:
  a pixel whose footprint is partly masked (0 < value < 1) is masked."""
  mask = np.ones((20, 24), np.float32)
  mask[8:11, 9:13] = 0.0
  intrinsics, target = (20.0, 20.0, 12.0, 10.0), (19.0, 19.0, 12.0, 10.0)
  out = masks.resample(mask, intrinsics, (0.05, 0.0, 0.0, 0.0), target, (20, 24))
  value = masks.lens.resample(mask[..., None], intrinsics, (0.05, 0.0, 0.0, 0.0), target,
                              (20, 24))[..., 0]
  np.testing.assert_array_equal(out, value >= masks.KEPT)
  partial = (value > 0.01) & (value < 0.99)
  assert partial.any() and not out[partial].any() and out.any()


def test_llff_masks_folder_white_keeps_and_names_may_add_or_swap_png(tmp_path, scene):
  export_llff(scene, str(tmp_path))
  names = sorted(os.listdir(tmp_path / "images"))
  os.rename(tmp_path / "masks" / names[0], tmp_path / "masks" / (names[0] + ".png"))
  for k, name in enumerate(names[1:3], 1):  # a .jpg mask file for a .png image would not load,
    os.rename(tmp_path / "images" / name, tmp_path / "images" / name.replace(".png", ".PNG"))
  back = load_llff(str(tmp_path))  # ... but the image's own extension may differ (.PNG)
  np.testing.assert_array_equal(back.masks, scene.masks)


def test_llff_factor_min_pools_full_size_masks(tmp_path, scene):
  export_llff(scene, str(tmp_path))
  back = load_llff(str(tmp_path), factor=2)
  np.testing.assert_array_equal(back.masks, scene.masks.reshape(5, 8, 2, 8, 2).min((2, 4)))


def test_every_export_round_trips_the_masks(tmp_path, scene):
  export.export_blender(scene, str(tmp_path / "blender"), split_at=3)
  train, test = (loaders.load_blender(str(tmp_path / "blender"), split=s)
                 for s in ("train", "test"))
  np.testing.assert_array_equal(np.concatenate([train.masks, test.masks]), scene.masks)
  half = loaders.load_blender(str(tmp_path / "blender"), half_res=True)
  np.testing.assert_array_equal(half.masks, scene.masks[:3].reshape(3, 8, 2, 8, 2).min((2, 4)))
  export.export_npz(scene, str(tmp_path / "s.npz"))
  np.testing.assert_array_equal(loaders.load_npz(str(tmp_path / "s.npz")).masks, scene.masks)
  export_llff(scene, str(tmp_path / "llff"))
  np.testing.assert_array_equal(load_llff(str(tmp_path / "llff")).masks, scene.masks)


def test_nerfstudio_write_round_trips_mask_paths(tmp_path, scene):
  (tmp_path / "images").mkdir()
  frames, paths = [], []
  for k in range(len(scene)):
    iio.imwrite(tmp_path / f"images/{k}.png", (scene.images[k] * 255).round().astype(np.uint8))
    masks.write(str(tmp_path / f"masks/{k}.png"), scene.masks[k])
    frames.append((f"images/{k}.png", scene.poses[k]))
    paths.append(f"masks/{k}.png")
  camera = {"fl_x": scene.focal, "fl_y": scene.focal, "cx": 8.0, "cy": 8.0, "w": 16, "h": 16}
  nerfstudio.write(str(tmp_path), frames, camera, {"nerf_jax_normalized": True}, paths)
  np.testing.assert_array_equal(nerfstudio.load(str(tmp_path))[0].masks, scene.masks)


def test_nerf_process_passes_masks_through(tmp_path):
  """The masks folder beside the photos becomes OUT's masks and each frame's mask_path (what
  process.process does after structure from motion, here with a made-up reconstruction)."""
  photos = tmp_path / "capture" / "photos"
  photos.mkdir(parents=True)
  (tmp_path / "capture" / "masks").mkdir()
  (tmp_path / "out" / "images").mkdir(parents=True)
  want = _random_masks(3, SIZE, SIZE, seed=4)
  names = [f"p{k}.jpg" for k in range(3)]
  for k, name in enumerate(names):
    for folder in (photos, tmp_path / "out" / "images"):
      iio.imwrite(folder / name, np.full((SIZE, SIZE, 3), 90, np.uint8))
    iio.imwrite(tmp_path / "capture" / "masks" / name, (want[k] * 255).astype(np.uint8))
  out = tmp_path / "out"
  paths = process.pass_masks(str(photos), names, str(out))
  assert paths == {name: f"masks/p{k}.png" for k, name in enumerate(names)}
  poses = capture_scene.ring_poses(3)
  rec = sfm.Reconstruction(
      names=names, poses=np.asarray(poses, np.float64),
      intrinsics=np.tile([10.0, 10.0, SIZE / 2, SIZE / 2], (3, 1)), dist=np.zeros((3, 4)),
      camera_ids=np.zeros(3, int), size=(SIZE, SIZE),
      points=np.random.default_rng(0).uniform(-1, 1, (50, 3)),
      colors=np.zeros((50, 3), np.uint8), point_errors=np.zeros(50), mean_error=0.0, colmap=None)
  process.write_dataset(str(out), rec, mask_paths=paths)
  np.testing.assert_array_equal(nerfstudio.load(str(out))[0].masks, want)
  assert process.pass_masks(str(tmp_path / "bare" / "photos"), ["p0.jpg"], str(out)) is None


def test_subsets_and_one_camera_carry_the_masks(scene):
  train, test = scene.split(3)
  np.testing.assert_array_equal(train.masks, scene.masks[:3])
  np.testing.assert_array_equal(test.mask(1), scene.masks[4])
  np.testing.assert_array_equal(scene.subset([4, 0]).masks, scene.masks[[4, 0]])
  assert scene.one_camera().masks is scene.masks
  mixed = Dataset([np.zeros((4, 4, 3)), np.zeros((2, 2, 3))], np.tile(np.eye(4), (2, 1, 1)),
                  (2.0, 2.0, 2.0, 2.0), masks=[np.ones((4, 4)), np.eye(2)])
  assert mixed.subset([1]).masks[0].tolist() == [[1.0, 0.0], [0.0, 1.0]]


@pytest.mark.parametrize("bad, match", [
    (np.full((5, 16, 16), np.nan), "values other than 0 and 1"),
    (np.ones((5, 16, 15)), "mask 0 is (16, 15)"),
    (np.ones((4, 16, 16)), "4 masks for 5 images"),
    (np.concatenate([np.ones((4, 16, 16)), np.zeros((1, 16, 16))]), "mask 4 ignores every"),
])
def test_bad_dataset_masks_are_one_line_errors(scene, bad, match):
  assert_data_error([match], dataclasses.replace, scene, masks=bad)


def test_bad_mask_files_are_one_line_errors(tmp_path):
  folder = _ngp_folder(tmp_path / "a", {0: {"mask_path": "masks/none.png"}}) if (
      tmp_path / "a").mkdir() is None else None
  assert_data_error(["frames[0].mask_path", "masks/none.png not found"], nerfstudio.load, folder)
  (tmp_path / "b").mkdir()
  folder = _ngp_folder(tmp_path / "b", dynamic={0: np.zeros((SIZE, SIZE + 1), np.uint8)})
  assert_data_error(["dynamic_mask_f_0.png", f"mask is {SIZE + 1}x{SIZE}", f"image is "
                     f"{SIZE}x{SIZE}"], nerfstudio.load, folder)
  (tmp_path / "c").mkdir()
  folder = _ngp_folder(tmp_path / "c", dynamic={1: np.ones((SIZE, SIZE), np.uint8)})
  assert_data_error(["dynamic_mask_f_1.png", "ignores every pixel"], nerfstudio.load, folder)


def test_a_missing_llff_mask_is_one_line(tmp_path, scene):
  export_llff(scene, str(tmp_path))
  os.remove(tmp_path / "masks" / "001.png")
  assert_data_error(["masks", "no mask for image 001.png"], load_llff, str(tmp_path))
  with pytest.raises(DataError):
    masks.read(str(tmp_path / "masks" / "001.png"), "white", "x")
