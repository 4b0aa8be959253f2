"""Tests of nerf_jax.data.convert_multiscale (the converter to mip-NeRF's multiscale format) and
nerf_jax.data.multicam (its reader and writer): the levels against a box filter written here,
the metadata, the loader round trip, and the exporters' refusal of per-image cameras; on
non-square images with per-split and per-view near and far, each level's size, focal and
principal point, the bounds, and the rays of known pixels against a projection written here."""

import json
import math

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data import export, loaders, multicam, convert_multiscale, scenes
from nerf_jax.data.dataset import DataError
from nerf_jax.train import train_batches
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
  assert convert_multiscale.main([f"--blender={blender}", f"--out={out}", f"--levels={LEVELS}"]) == 0
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


def test_rgba_multiscale_is_scored_on_white_under_auto_as_blender_folders_are(folders, tmp_path):
  blender, out = folders
  assert loaders.auto_background(out) == (
      "white", "the convention of mip-NeRF's multiscale data (Blender's RGBA, on white)")
  assert loaders.auto_background(blender)[0] == "white"  # the rule it follows
  train, test = load_data({"path": out})  # data.background='auto', the default
  white_train, white_test = load_data({"path": out, "background": "white"})
  assert train.background == test.background == (1.0, 1.0, 1.0)
  for k in range(len(test)):
    np.testing.assert_array_equal(test.image(k), white_test.image(k))
  # RGB images (no opacity to composite): black, as for Blender folders of RGB images.
  rgb = tmp_path / "rgb"
  convert_multiscale.convert(blender, str(rgb), levels=2)
  for path in rgb.glob("images_*/*.png"):
    iio.imwrite(path, iio.imread(path)[..., :3])
  assert loaders.auto_background(str(rgb))[0] == "black"
  # A transforms.json beside it is read first (nerfstudio's format): black.
  convert_multiscale.convert(blender, str(tmp_path / "both"), levels=1)
  (tmp_path / "both" / "transforms.json").write_text("{}")
  assert loaders.auto_background(str(tmp_path / "both"))[0] == "black"
  # The built-in multiscale scene is no folder: black, as every built-in scene.
  assert loaders.auto_background("")[0] == "black"


def test_one_level_is_one_camera(folders, tmp_path):
  blender, _ = folders
  convert_multiscale.convert(blender, str(tmp_path), levels=1)
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
    convert_multiscale.convert(str(tmp_path), str(tmp_path / "x"))


# Non-square images (rows ≠ columns at every level) and near/far that differ between splits
# and between views: a swapped height and width, a cy taken from the width or a wrong near/far
# fail here, where the square images above with one near and far cannot tell.

ROWS, COLS = 12, 20  # level 0; levels 1 and 2 are 6×10 and 3×5 (no odd row or column dropped)
ANGLE_X = 0.9  # camera_angle_x: focal_0 = 0.5·COLS / tan(0.45)


def _rotation(seed):
  """float64 [3, 3], a random rotation (det +1)."""
  q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
  q = q * np.sign(np.diag(r))
  return q if np.linalg.det(q) > 0 else -q


def _pose(seed):
  """float64 [4, 4], a camera-to-world matrix: a random rotation, a random position."""
  pose = np.eye(4)
  pose[:3, :3], pose[:3, 3] = _rotation(seed), np.random.default_rng(seed + 50).normal(size=3)
  return pose


def _non_square_blender(root):
  """A Blender folder of ROWS×COLS RGBA views with their own near and far per split (train:
  2 views, near 1.25, far 5.5; test: 1 view, near 2.5, far 7.0); returns {split: (poses,
  images float64 [H, W, 4] as written, near, far)}."""
  splits = {"train": (2, 1.25, 5.5), "test": (1, 2.5, 7.0)}
  written = {}
  for s, (split, (count, near, far)) in enumerate(splits.items()):
    frames, poses, images = [], [], []
    for v in range(count):
      rng = np.random.default_rng(10 * s + v)
      rgba = rng.integers(0, 256, (ROWS, COLS, 4)).astype(np.uint8)
      rgba[..., 3] = rng.integers(128, 256, (ROWS, COLS))  # partly opaque everywhere
      iio.imwrite(root / f"{split}_{v}.png", rgba)
      poses.append(_pose(10 * s + v))
      images.append(rgba.astype(np.float64) / 255)
      frames.append({"file_path": f"./{split}_{v}", "transform_matrix": poses[-1].tolist()})
    (root / f"transforms_{split}.json").write_text(json.dumps(
        {"camera_angle_x": ANGLE_X, "near": near, "far": far, "frames": frames}))
    written[split] = (poses, images, near, far)
  return written


def _expected_camera(level):
  """(height, width, focal, cx, cy) of `level` of the ROWS×COLS views, written out: each level
  halves the rows and the columns; the focal halves; the principal point is the centre."""
  height, width = ROWS // 2 ** level, COLS // 2 ** level
  focal = 0.5 * COLS / math.tan(0.5 * ANGLE_X) / 2 ** level
  return height, width, focal, width / 2.0, height / 2.0


@pytest.fixture(scope="module")
def non_square(tmp_path_factory):
  """(what the Blender folder holds, the multiscale folder converted from it at 3 levels)."""
  root = tmp_path_factory.mktemp("non_square")
  (root / "blender").mkdir()
  written = _non_square_blender(root / "blender")
  convert_multiscale.convert(str(root / "blender"), str(root / "ms"), levels=3)
  return written, str(root / "ms")


def test_non_square_levels_have_their_own_height_width_focal_and_pix2cam(non_square):
  written, out = non_square
  meta = json.load(open(f"{out}/metadata.json"))
  for split, (poses, images, near, far) in written.items():
    m = meta[split]
    for v in range(len(poses)):
      for j in range(3):
        k = 3 * v + j
        height, width, f, cx, cy = _expected_camera(j)
        assert (m["height"][k], m["width"][k]) == (height, width)
        np.testing.assert_allclose(m["focal"][k], f, rtol=1e-12)
        # mip-NeRF's pix2cam: (x + 0.5, y + 0.5, 1) -> ((x + 0.5 - cx)/f, -(y + 0.5 - cy)/f, -1)
        np.testing.assert_allclose(m["pix2cam"][k], [[1 / f, 0, -cx / f], [0, -1 / f, cy / f],
                                                     [0, 0, -1]], rtol=1e-12)
        assert (m["near"][k], m["far"][k]) == (near, far)  # the split's own, not 2 and 6
        got = iio.imread(f"{out}/{m['file_path'][k]}")
        assert got.shape == (height, width, 4)


@pytest.mark.parametrize("with_pix2cam", [True, False])
def test_non_square_loader_cameras_images_and_bounds(non_square, tmp_path, with_pix2cam):
  """Each image's (height, width, fx, fy, cx, cy) and pixels, and the split's near and far,
  from the pix2cam matrices or (without them) from focal, width and height."""
  written, out = non_square
  if not with_pix2cam:  # the same folder, its metadata without the pix2cam column
    meta = json.load(open(f"{out}/metadata.json"))
    for split in meta.values():
      del split["pix2cam"]
    (tmp_path / "metadata.json").write_text(json.dumps(meta))
    for split in ("train", "test"):
      (tmp_path / f"images_{split}").symlink_to(f"{out}/images_{split}")
    out = str(tmp_path)
  for split, (poses, images, near, far) in written.items():
    ds = multicam.load(out, split=split)
    assert (ds.near, ds.far) == (near, far)
    for v, rgba in enumerate(images):
      for j, level in enumerate(_box_levels(rgba)):
        k = 3 * v + j
        height, width, f, cx, cy = _expected_camera(j)
        got_h, got_w, intrinsics = ds.cameras.camera(k)
        assert (got_h, got_w) == (height, width)
        np.testing.assert_allclose(intrinsics, (f, f, cx, cy), rtol=1e-12)
        assert ds.image(k).shape == (height, width, 3)
        # Composited on black: colour times alpha, the box mean's, within 8-bit rounding.
        np.testing.assert_allclose(ds.image(k), level[..., :3] * level[..., 3:],
                                   atol=1.5 / 255)
        np.testing.assert_array_equal(ds.poses[k], np.float32(poses[v]))


def test_per_view_near_and_far_give_the_smallest_near_and_the_largest_far(tmp_path):
  rgba = np.full((ROWS, COLS, 4), 0.5)
  nears, fars = (3.0, 1.5, 2.2), (4.0, 6.5, 5.0)  # neither bound is the first view's
  entries = [{"rgba": rgba, "cam2world": np.eye(4), "focal": 9.0, "label": 0, "near": n,
              "far": f, "lossmult": 1.0} for n, f in zip(nears, fars)]
  multicam.write(str(tmp_path), {"train": entries})
  meta = json.load(open(tmp_path / "metadata.json"))["train"]
  assert (meta["near"], meta["far"]) == (list(nears), list(fars))
  ds = multicam.load(str(tmp_path))
  assert (ds.near, ds.far) == (1.5, 6.5)


def test_a_ray_through_a_pixel_of_any_level_meets_the_point_it_images(non_square):
  """The ray of pixel (x, y) at level j, as training draws it (train_batches.pixel_rays_of over
  every image's own camera) and as evaluation draws it (camera_rays of the image's camera),
  against a projection written here: a point along it projects, by the level-0 pinhole of
  the Blender convention (camera looks down -z, +y up, rows down), to level-0 coordinates
  (2^j (x + 0.5), 2^j (y + 0.5))."""
  written, out = non_square
  ds = multicam.load(out, split="train")
  poses = written["train"][0]
  data = train_batches.make_train_data(ds, (None, None, None, ds.near, ds.far, 0.5, False),
                                       np.zeros(3, np.float32))
  _, _, f0, cx0, cy0 = _expected_camera(0)
  picks = [(k, x, y) for k in range(len(ds)) for x, y in ((0, 0), (1, 2), (4, 1))
           if x < ds.cameras.width[k] and y < ds.cameras.height[k]]
  image = np.array([k for k, _, _ in picks], np.int32)
  pixel = np.array([y * ds.cameras.width[k] + x for k, x, y in picks], np.int32)
  trained = train_batches.pixel_rays_of(data, image, pixel)
  for n, (k, x, y) in enumerate(picks):
    height, width, intrinsics = ds.cameras.camera(k)
    evaluated = rays_lib.camera_rays(height, width, intrinsics, ds.poses[k], ds.near, ds.far)
    pose, scale = poses[k // 3], 2.0 ** (k % 3)
    for origin, direction in ((trained.origins[n], trained.directions[n]),
                              (evaluated.origins[y, x], evaluated.directions[y, x])):
      np.testing.assert_allclose(origin, pose[:3, 3], atol=1e-6)
      point = pose[:3, :3].T @ (np.float64(origin) + 3.0 * np.float64(direction) - pose[:3, 3])
      depth = -point[2]
      assert depth > 0  # in front of the camera
      u, v = cx0 + f0 * point[0] / depth, cy0 - f0 * point[1] / depth
      np.testing.assert_allclose([u, v], [scale * (x + 0.5), scale * (y + 0.5)], atol=1e-4,
                                 err_msg=f"image {k}, pixel ({x}, {y})")
