"""The transforms.json loader (nerf_jax.data.nerfstudio): intrinsics, distortion, splits,
re-orientation, one-line errors. Photos come from nerf_jax.data.scenes.capture's own ray tracer."""

import itertools
import json

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.data.scenes import capture as capture_scene
from tests.helpers import assert_data_error, load_data
from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data import nerfstudio, orient, pointcloud

SIZE = (48, 56)  # (height, width)


def _write(tmp_path, frames, top=None, images=None, fmt="png"):
  """A transforms.json folder: frames = list of (pose, per-frame dict)."""
  (tmp_path / "images").mkdir(exist_ok=True)
  entries = []
  for k, (pose, fields) in enumerate(frames):
    name = f"images/f_{k:02d}.{fmt}"
    iio.imwrite(tmp_path / name, images[k])
    entries.append({"file_path": name, "transform_matrix": np.asarray(pose).tolist(), **fields})
  meta = {"nerf_jax_normalized": True, "near": 1.0, "far": 8.0, **(top or {}), "frames": entries}
  (tmp_path / "transforms.json").write_text(json.dumps(meta))
  return str(tmp_path)


def _u8(image):
  return (np.clip(image, 0, 1) * 255).round().astype(np.uint8)


def test_per_frame_intrinsics_are_kept_and_each_frames_distortion_removed(tmp_path):
  poses = capture_scene.ring_poses(2, seed=3)
  cams = [((60.0, 62.0, 28.3, 23.6), (-0.15, 0.04, 0.003, -0.002)),
          ((64.0, 64.0, 27.7, 24.4), (0.08, 0.0, 0.0, 0.0))]
  photos = [_u8(capture_scene.render(p, *SIZE, k, d, octaves=1)) for p, (k, d) in zip(poses, cams)]
  fields = [dict(zip(("fl_x", "fl_y", "cx", "cy"), k), **dict(zip(("k1", "k2", "p1", "p2"), d)))
            for k, d in cams]
  path = _write(tmp_path, list(zip(poses, fields)), {"camera_model": "OPENCV"}, photos)
  dataset, names, test_names = nerfstudio.load(path)
  assert names == ["images/f_00.png", "images/f_01.png"] and test_names is None
  for k, (intrinsics, _) in enumerate(cams):  # each frame keeps its own pinhole
    assert dataset.cameras.camera(k)[:2] == SIZE
    np.testing.assert_allclose(dataset.cameras.camera(k)[2],
                               np.subtract(intrinsics, [0, 0, 0.5, 0.5]), atol=1e-9)
  np.testing.assert_allclose(dataset.poses, poses, atol=1e-6)
  for k, pose in enumerate(poses):
    # Ground truth: the scene through the rays nerf_jax casts for the frame's camera, and the
    # same camera half a pixel off (what a wrong pixel-centre convention would give).
    errors = []
    for shift in (0.0, 0.5, -0.5):
      intrinsics = np.add(dataset.cameras.camera(k)[2], [0, 0, shift, shift])
      origins, directions = rays_lib.get_rays_intrinsics(*SIZE, tuple(intrinsics), pose)
      truth = capture_scene.render_rays(origins, directions, octaves=1).reshape(*SIZE, 3)
      inner = np.s_[4:-4, 4:-4]  # undistorted, the photo does not cover the border
      lit = truth[inner].max(-1) > 0.05  # the object, not the black background
      error = lambda image: np.median(np.abs(image[inner] - truth[inner])[lit])  # not edges
      errors.append(error(dataset.images[k]))
      if shift == 0.0:  # the mean error: the distortion moves the outer pixels most
        mean = lambda image: np.mean(np.abs(image[inner] - truth[inner])[lit])
        raw, fixed = mean(photos[k] / 255.0), mean(dataset.images[k])  # raw: not undistorted
    gain = 0.8 if k == 0 else 1.0  # frame 0's k1 = -0.15 moves its pixels most
    assert errors[0] < 0.015 and errors[0] < 0.5 * min(errors[1:]) and fixed < gain * raw, (
        k, errors, raw, fixed)


def test_camera_angle_and_image_size_scaling(tmp_path):
  pose = capture_scene.ring_poses(1)[0]
  photo = _u8(capture_scene.render(pose, *SIZE, (50.0, 50.0, 28.0, 24.0)))
  # instant-ngp style: camera_angle_x, no camera_model; w, h twice the image (a downscaled copy)
  angle = 2 * np.arctan(0.5 * 112 / 100.0)
  path = _write(tmp_path, [(pose, {})], {"camera_angle_x": angle, "w": 112, "h": 96},
                [photo])
  dataset, _, _ = nerfstudio.load(path)
  np.testing.assert_allclose(dataset.intrinsics, (50.0, 50.0, 27.5, 23.5), atol=1e-9)
  np.testing.assert_allclose(dataset.images[0], photo / 255.0, atol=1e-6)  # no resampling


def test_factor_block_averages_and_scales_intrinsics(tmp_path):
  photo = np.random.default_rng(0).integers(0, 256, (8, 12, 3)).astype(np.uint8)
  path = _write(tmp_path, [(np.eye(4), {})], {"fl_x": 10.0, "cx": 6.0, "cy": 4.0}, [photo])
  dataset, _, _ = nerfstudio.load(path, factor=2)
  want = photo.reshape(4, 2, 6, 2, 3).mean((1, 3)) / 255.0
  np.testing.assert_allclose(dataset.images[0], want, atol=1e-6)
  np.testing.assert_allclose(dataset.intrinsics, (5.0, 5.0, 2.5, 1.5), atol=1e-9)


def test_split_every_8th_or_as_the_file_says(tmp_path):
  photos = [np.full((4, 4, 3), k, np.uint8) for k in range(10)]
  frames = [(np.eye(4), {}) for _ in range(10)]
  config = {"path": _write(tmp_path, frames, {"fl_x": 5.0}, photos)}
  train, test = load_data(config)
  assert [round(im[0, 0, 0] * 255) for im in test.images] == [0, 8]
  assert len(train) == 8
  meta = json.loads((tmp_path / "transforms.json").read_text())
  meta["test_filenames"] = ["images/f_03.png", "./images/f_05.png"]
  (tmp_path / "transforms.json").write_text(json.dumps(meta))
  train, test = load_data(config)
  assert [round(im[0, 0, 0] * 255) for im in test.images] == [3, 5] and len(train) == 8


def test_unnormalised_folder_is_reoriented_and_scaled(tmp_path):
  """An ns-process-data-like folder in an arbitrary similarity frame with its sparse points."""
  poses = capture_scene.ring_poses(12, seed=1)
  points = np.random.default_rng(0).uniform(-0.6, 0.6, (300, 3)) * [1.0, 0.8, 0.5]
  angle = 0.7
  rot = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)],
                  [0, np.sin(angle), np.cos(angle)]]) @ np.array([[0, 1, 0], [1, 0, 0],
                                                                  [0, 0, -1]])
  sim = np.eye(4)
  sim[:3, :3], sim[:3, 3] = 2.5 * rot, [3.0, -1.0, 7.0]
  moved_poses, moved_points = orient.apply(sim, poses, points)
  pointcloud.write_ply(tmp_path / "sparse_pc.ply", moved_points,
                       np.zeros((300, 3), np.uint8))
  path = _write(tmp_path, [(p, {}) for p in moved_poses],
                {"fl_x": 5.0, "ply_file_path": "sparse_pc.ply", "nerf_jax_normalized": None},
                [np.zeros((4, 4, 3), np.uint8)] * 12)
  dataset, _, _ = nerfstudio.load(path)
  # Up is +z again: the ring of cameras lies in a horizontal plane (z spread only from elevation).
  centres = dataset.poses[:, :3, 3]
  normal = np.linalg.svd(centres - centres.mean(0))[2][2]
  assert abs(normal[2]) > 0.99
  # Relative geometry is kept: rotations between cameras and ratios of distances.
  rel = lambda p: np.einsum("ji,jk->ik", p[0, :3, :3], p[1, :3, :3])
  np.testing.assert_allclose(rel(dataset.poses), rel(poses), atol=1e-5)
  ratio = lambda c: np.linalg.norm(c[1] - c[0]) / np.linalg.norm(c[2] - c[0])
  np.testing.assert_allclose(ratio(centres), ratio(poses[:, :3, 3]), rtol=1e-5)
  # The points, carried by the same similarity, have a centred 2-98 percentile box that is
  # [-1, 1] on its longest side.
  step = lambda c: np.linalg.norm(c[1] - c[0])
  scale = step(centres) / step(poses[:, :3, 3])
  rot = dataset.poses[0, :3, :3] @ poses[0, :3, :3].T
  mapped = scale * (points - poses[0, :3, 3]) @ rot.T + centres[0]
  lo, hi = np.percentile(mapped, [2, 98], axis=0)
  np.testing.assert_allclose(np.max(hi - lo), 2.0, rtol=1e-5)
  np.testing.assert_allclose(lo + hi, 0.0, atol=1e-5)
  assert dataset.near < dataset.far


def test_ply_roundtrip_ascii_and_binary(tmp_path):
  rng = np.random.default_rng(0)
  points, colors = rng.normal(size=(7, 3)), rng.integers(0, 256, (7, 3)).astype(np.uint8)
  pointcloud.write_ply(tmp_path / "a.ply", points, colors)
  got, got_colors = pointcloud.read_ply(tmp_path / "a.ply")
  np.testing.assert_allclose(got, points, atol=1e-6)
  np.testing.assert_array_equal(got_colors, colors)
  table = np.zeros(7, [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"), ("green", "u1"),
                       ("blue", "u1")])
  for k, n in enumerate("xyz"):
    table[n] = points[:, k]
  header = ("ply\nformat binary_little_endian 1.0\nelement vertex 7\nproperty double x\n"
            "property double y\nproperty double z\nproperty uchar red\nproperty uchar green\n"
            "property uchar blue\nend_header\n")
  (tmp_path / "b.ply").write_bytes(header.encode() + table.tobytes())
  np.testing.assert_array_equal(pointcloud.read_ply(tmp_path / "b.ply")[0], points)


@pytest.mark.parametrize("top,frame,match", [
    ({"camera_model": "OPENCV_FISHEYE"}, {}, ["frames[0].camera_model", "OPENCV_FISHEYE"]),
    ({}, {}, ["frames[0]", "'fl_x'"]),
    ({"fl_x": -3.0}, {}, ["frames[0]", "positive"]),
    ({"fl_x": 5.0, "w": 8, "h": 4}, {}, ["frames[0]", "aspect ratio"]),
    ({"fl_x": 5.0, "ply_file_path": "nope.ply", "nerf_jax_normalized": None}, {},
     ["nope.ply not found"]),
])
def test_bad_files_give_one_line(tmp_path, top, frame, match):
  path = _write(tmp_path, [(np.eye(4), frame)], top, [np.zeros((4, 4, 3), np.uint8)])
  assert_data_error(match, nerfstudio.load, path)


def test_mixed_sizes_keep_each_frames_size_and_camera(tmp_path):
  images = [np.full((4, 4, 3), 10, np.uint8), np.full((4, 6, 3), 20, np.uint8)]
  path = _write(tmp_path, [(np.eye(4), {}), (np.eye(4), {})], {"fl_x": 5.0}, images)
  dataset = nerfstudio.load(path)[0]
  assert dataset.mixed_sizes and [im.shape for im in dataset.images] == [(4, 4, 3), (4, 6, 3)]
  assert dataset.cameras.camera(1) == (4, 6, (5.0, 5.0, 2.5, 1.5))
  np.testing.assert_allclose(dataset.image(1), 20 / 255, atol=1e-7)


def test_frames_of_one_camera_share_it(tmp_path):
  """One camera, given per frame: one pinhole, no per-image cameras (today's path)."""
  images = [np.full((4, 4, 3), 10, np.uint8)] * 3
  path = _write(tmp_path, [(np.eye(4), {"fl_x": 5.0, "cx": 2.2})] * 3, {}, images)
  dataset = nerfstudio.load(path)[0]
  assert dataset.image_cameras is None and dataset.images.shape == (3, 4, 4, 3)
  assert dataset.intrinsics == pytest.approx((5.0, 5.0, 1.7, 1.5))


def _numbered(tmp_path, num, top=None, fields=None):
  """A folder of `num` 4x4 frames, frame k all k; fields: per-frame dicts."""
  photos = [np.full((4, 4, 3), k, np.uint8) for k in range(num)]
  frames = [(np.eye(4), (fields or [{}] * num)[k]) for k in range(num)]
  return _write(tmp_path, frames, {"fl_x": 5.0, **(top or {})}, photos)


def test_frames_without_an_image_are_skipped_with_one_line(tmp_path, capsys):
  path = _numbered(tmp_path, 12)
  gone = [1, 2, 4, 7, 9, 10]  # half: still skipped
  for k in gone:
    (tmp_path / "images" / f"f_{k:02d}.png").unlink()
  dataset, names, _ = nerfstudio.load(path)
  kept = [k for k in range(12) if k not in gone]
  assert names == [f"images/f_{k:02d}.png" for k in kept]
  np.testing.assert_array_equal(dataset.images[:, 0, 0, 0] * 255, kept)
  lines = capsys.readouterr().out.splitlines()
  assert len(lines) == 1, lines
  assert "skipped 6 of 12" in lines[0] and str(tmp_path / "images") in lines[0]
  assert lines[0].endswith("f_01.png, f_02.png, f_04.png, f_07.png, f_09.png, …"), lines[0]


def test_most_or_all_images_missing_is_one_line_naming_the_folder(tmp_path):
  path = _numbered(tmp_path, 12)
  for k in range(7):
    (tmp_path / "images" / f"f_{k:02d}.png").unlink()
  folder = str(tmp_path / "images")
  assert_data_error(["7 of 12", folder, "factor"], nerfstudio.load, path)
  for k in range(7, 12):
    (tmp_path / "images" / f"f_{k:02d}.png").unlink()
  assert_data_error(["none of the 12", folder], nerfstudio.load, path)


def _sharp_reference(sharpness, threshold, window=3):
  """Brute force: a rated frame is kept unless it is below threshold x the mean of the rated
  frames at most `window` rated places away."""
  rated = [k for k, s in enumerate(sharpness) if not np.isnan(s)]
  keep = []
  for k, s in enumerate(sharpness):
    if np.isnan(s):
      keep.append(True)
      continue
    near = [sharpness[j] for j in rated if abs(rated.index(j) - rated.index(k)) <= window]
    keep.append(bool(s >= threshold * sum(near) / len(near)))
  return keep


def test_sharp_frames_drop_the_blurrier_than_their_neighbours():
  # By hand: frame 4's rated neighbours are all 7 rated frames (frame 1 has no sharpness), mean
  # 62/7 = 8.86; 2 < 0.5 x 8.86, dropped; frame 0's window (10, 10, 10, 2) has mean 8: kept.
  sharpness = [10, np.nan, 10, 10, 2, 10, 10, 10]
  assert nerfstudio.sharp_frames(sharpness, 0.5).tolist() == [True] * 4 + [False] + [True] * 3
  assert nerfstudio.sharp_frames(sharpness, 0.0).all()  # 0 = off
  rng = np.random.default_rng(0)
  sharpness = rng.uniform(5, 40, 60)
  sharpness[rng.choice(60, 8, replace=False)] = np.nan
  for threshold in (0.5, 0.8, 1.0):
    got = nerfstudio.sharp_frames(sharpness, threshold).tolist()
    assert got == _sharp_reference(sharpness, threshold), threshold
    assert threshold < 0.8 or not all(got)


def test_min_sharpness_drops_frames_at_load(tmp_path, capsys):
  values = [30.0, 31.0, 29.0, 5.0, 30.0, 32.0, 28.0]
  fields = [{"sharpness": v} for v in values]
  config = {"path": _numbered(tmp_path, 7, fields=fields), "holdout_from": 3}
  train, test = load_data(config)  # default 0: all kept, nothing printed
  assert len(train) + len(test) == 7 and capsys.readouterr().out == ""
  train, test = load_data({**config, "min_sharpness": 0.5})
  kept = np.concatenate([train.images, test.images])[:, 0, 0, 0] * 255
  np.testing.assert_array_equal(kept, [0, 1, 2, 4, 5, 6])
  out = capsys.readouterr().out.splitlines()
  assert len(out) == 1 and "dropped 1 of 7" in out[0], out


def _corners(box):
  return np.array(list(itertools.product(*np.asarray(box, np.float64).T)))


def _similarity(before, after):
  """The similarity x -> s R x + t that took the poses `before` to `after` (float [N, 4, 4]),
  recovered from two cameras: float64 [4, 4]."""
  before, after = np.asarray(before, np.float64), np.asarray(after, np.float64)
  rot = after[0, :3, :3] @ before[0, :3, :3].T
  step = lambda p: np.linalg.norm(p[1, :3, 3] - p[0, :3, 3])
  transform = np.eye(4)
  transform[:3, :3] = step(after) / step(before) * rot
  transform[:3, 3] = after[0, :3, 3] - transform[:3, :3] @ before[0, :3, 3]
  return transform


def test_aabb_from_aabb_scale_by_hand(tmp_path):
  # instant-ngp: ngp = 0.33 x + 0.5, box [0.5 - k/2, 0.5 + k/2]^3 -> x in +-(k/2) / 0.33.
  (tmp_path / "a").mkdir()
  path = _numbered(tmp_path / "a", 2, {"aabb_scale": 4})  # nerf_jax_normalized: no transform
  np.testing.assert_allclose(nerfstudio.load(path)[0].aabb, [[-2 / 0.33] * 3, [2 / 0.33] * 3],
                             rtol=1e-6)
  # The subject's box (core): instant-ngp's unit cube, aabb_scale 1: +-0.5 / 0.33.
  np.testing.assert_allclose(nerfstudio.load(path)[0].core,
                             [[-0.5 / 0.33] * 3, [0.5 / 0.33] * 3], rtol=1e-6)
  # The file's scale and offset: x = (ngp - offset) / scale, ngp in [-0.5, 1.5].
  (tmp_path / "b").mkdir()
  path = _numbered(tmp_path / "b", 2, {"aabb_scale": 2, "scale": 0.5, "offset": [0.5, 0.4, 0.6]})
  np.testing.assert_allclose(nerfstudio.load(path)[0].aabb,
                             [[-2.0, -1.8, -2.2], [2.0, 2.2, 1.8]], rtol=1e-6)
  # An un-normalised folder is moved and scaled: the box goes with the poses, and is the
  # axis-aligned box of its eight moved corners; every split keeps it.
  (tmp_path / "c").mkdir()
  poses = capture_scene.ring_poses(8, seed=2)
  poses[:, :3, 3] = poses[:, :3, 3] * 1.7 + [0.4, -0.3, 1.0]
  path = _write(tmp_path / "c", [(p, {}) for p in poses],
                {"fl_x": 5.0, "aabb_scale": 1, "nerf_jax_normalized": None},
                [np.zeros((4, 4, 3), np.uint8)] * 8)
  dataset = nerfstudio.load(path)[0]
  transform = _similarity(poses, dataset.poses)
  moved = _corners([[-0.5 / 0.33] * 3, [0.5 / 0.33] * 3]) @ transform[:3, :3].T + transform[:3, 3]
  np.testing.assert_allclose(dataset.aabb, [moved.min(0), moved.max(0)], atol=1e-4)
  assert dataset.aabb.dtype == np.float32 and dataset.aabb.shape == (2, 3)
  train, test = nerfstudio.load_split(path)
  np.testing.assert_array_equal(train.aabb, dataset.aabb)
  np.testing.assert_array_equal(test.aabb, dataset.aabb)


def test_images_n_preferred_over_downscaling(tmp_path):
  photos = [np.full((8, 12, 3), 90, np.uint8), np.full((8, 12, 3), 30, np.uint8)]
  path = _write(tmp_path, [(np.eye(4), {}), (np.eye(4), {})],
                {"fl_x": 10.0, "cx": 6.0, "cy": 4.0}, photos)
  (tmp_path / "images_4").mkdir()
  iio.imwrite(tmp_path / "images_4" / "f_00.png", np.full((2, 3, 3), 200, np.uint8))
  dataset, _, _ = nerfstudio.load(path, factor=4)
  # frame 0 from images_4/ (not 90, the full image's average); frame 1 block-averaged
  np.testing.assert_allclose(dataset.images[:, 0, 0, 0] * 255, [200, 30], atol=1e-4)
  np.testing.assert_allclose(dataset.intrinsics, (2.5, 2.5, 1.0, 0.5), atol=1e-9)
  (tmp_path / "images" / "f_00.png").unlink()  # only in images_4/: not missing
  np.testing.assert_allclose(nerfstudio.load(path, factor=4)[0].images[:, 0, 0, 0] * 255,
                             [200, 30], atol=1e-4)


def test_ns_process_data_folder_loads(tmp_path):
  """What nerfstudio's ns-process-data writes: OPENCV camera, w/h of the full images,
  images/frame_%05d.png with masks and images_2/ copies, applied_transform, sparse_pc.ply
  (already in the poses' frame), no near/far. The scene box comes from the points."""
  poses = capture_scene.ring_poses(6, seed=4)
  points = np.random.default_rng(1).normal(0.0, 0.4, (400, 3))
  pointcloud.write_ply(tmp_path / "sparse_pc.ply", points, np.zeros((400, 3), np.uint8))
  for folder in ("images", "images_2", "masks"):
    (tmp_path / folder).mkdir()
  frames = []
  for k, pose in enumerate(poses):
    name = f"frame_{k + 1:05d}.png"
    iio.imwrite(tmp_path / "images" / name, np.full((8, 12, 3), 40 * k, np.uint8))
    iio.imwrite(tmp_path / "images_2" / name, np.full((4, 6, 3), 40 * k + 1, np.uint8))
    iio.imwrite(tmp_path / "masks" / name, np.full((8, 12), 255, np.uint8))
    frames.append({"file_path": f"images/{name}", "mask_path": f"masks/{name}",
                   "transform_matrix": pose.tolist(), "colmap_im_id": k + 1})
  meta = {"w": 12, "h": 8, "fl_x": 11.0, "fl_y": 11.0, "cx": 6.0, "cy": 4.0, "k1": 0.0,
          "k2": 0.0, "p1": 0.0, "p2": 0.0, "camera_model": "OPENCV", "frames": frames,
          "applied_transform": [[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 0]],
          "ply_file_path": "sparse_pc.ply"}
  (tmp_path / "transforms.json").write_text(json.dumps(meta))
  train, test = load_data({"path": str(tmp_path), "factor": 2})
  assert (len(train), len(test)) == (5, 1) and (train.height, train.width) == (4, 6)
  np.testing.assert_allclose(test.images[0, 0, 0, 0] * 255, 1, atol=1e-4)  # images_2/
  np.testing.assert_allclose(train.intrinsics, (5.5, 5.5, 2.5, 1.5), atol=1e-9)
  # aabb: the points carried with the poses, their 1-99 percentile box padded by 10 %.
  transform = _similarity(poses[1:], train.poses)
  moved = points @ transform[:3, :3].T + transform[:3, 3]
  lo, hi = np.percentile(moved, [1, 99], axis=0)
  np.testing.assert_allclose(train.aabb, [lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo)], atol=1e-4)
  np.testing.assert_array_equal(test.aabb, train.aabb)
