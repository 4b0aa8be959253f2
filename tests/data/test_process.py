"""nerf-process on a small rendered capture: poses, focal and the conventions of what it writes
(against pycolmap's own projection), one line for every bad input; photos of several sizes and
cameras (--nosingle_camera), each frame with its own; and the capture benchmark's
fair comparison: true poses mapped into the processed frame, the folder that differs only in them,
scoring a run at given poses."""

import dataclasses
import json
import os
import re
import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest
import scipy.optimize
import scipy.spatial.transform

from nerf_jax.data.scenes import capture as capture_scene
from tests.helpers import assert_data_error, load_data, similarity
from nerf_jax.run import config_lib, experiment
from nerf_jax.cameras import rays as rays_lib
from nerf_jax.bench import capture as capture_bench
from nerf_jax.data import lens, nerfstudio, pointcloud, process, sfm

# The capture extra (structure from motion); the tests say how to install it when it is missing.
pycolmap = pytest.importorskip(
    "pycolmap", reason='needs pycolmap; install with: pip install -e ".[capture]"')

NUM_VIEWS, SIZE, FOCAL = 24, 128, 160.0
from tests.helpers import ROOT


def _photograph(folder, num_views=NUM_VIEWS):
  os.makedirs(folder, exist_ok=True)
  poses = capture_scene.ring_poses(num_views)
  for k, pose in enumerate(poses):
    image = capture_scene.render(pose, SIZE, SIZE, (FOCAL, FOCAL, SIZE / 2, SIZE / 2))
    iio.imwrite(os.path.join(folder, f"view_{k:02d}.jpg"),
                (image * 255).round().astype(np.uint8), quality=95)
  return poses


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
  root = tmp_path_factory.mktemp("capture")
  poses = _photograph(str(root / "photos"))
  # One thread: COLMAP repeats itself exactly (with two, a CI run's rotations erred 0.73°).
  summary = process.process(str(root / "out"), images=str(root / "photos"), log=lambda _: None,
                            num_threads=1)
  return root, poses, summary


def test_recovers_the_cameras(processed):
  root, truth, summary = processed
  meta = json.loads((root / "out" / "transforms.json").read_text())
  assert summary["num_registered"] == NUM_VIEWS and len(meta["frames"]) == NUM_VIEWS
  index = [int(f["file_path"][-6:-4]) for f in meta["frames"]]
  poses = np.array([f["transform_matrix"] for f in meta["frames"]])
  true = truth[index].astype(np.float64)
  scale, rot, trans = similarity(poses[:, :3, 3], true[:, :3, 3])
  centres = scale * poses[:, :3, 3] @ rot.T + trans
  centre_err = np.linalg.norm(centres - true[:, :3, 3], axis=-1) / np.linalg.norm(
      true[:, :3, 3], axis=-1)
  rel = np.einsum("ij,njk,nlk->nil", rot, poses[:, :3, :3], true[:, :3, :3])
  angles = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
  # The goals (median rotation <= 0.5°, centre error <= 1% of the camera distance),
  # here on 128-pixel photos; the worst camera within a few times that.
  assert np.median(angles) < 0.5 and np.median(centre_err) < 0.01, (angles, centre_err)
  assert np.max(angles) < 3.0 and np.max(centre_err) < 0.05, (angles, centre_err)
  bench_angles, bench_centre_err = capture_bench.pose_errors(poses, true)  # what the bench says
  np.testing.assert_allclose(bench_angles, angles, atol=1e-6)
  np.testing.assert_allclose(bench_centre_err, centre_err, atol=1e-9)
  assert abs(meta["fl_x"] / FOCAL - 1) < 0.02 and abs(meta["fl_y"] / FOCAL - 1) < 0.02
  assert meta["w"] == SIZE and meta["h"] == SIZE and meta["camera_model"] == "OPENCV"
  # Upright and in the box: the cameras' ring is horizontal, the scene centred at the origin.
  normal = np.linalg.svd(poses[:, :3, 3] - poses[:, :3, 3].mean(0))[2][2]
  assert abs(normal[2]) > 0.98
  points, _ = pointcloud.read_ply(root / "out" / "sparse_pc.ply")
  lo, hi = np.percentile(points, [2, 98], axis=0)
  np.testing.assert_allclose(np.max(hi - lo), 2.0, rtol=1e-4)
  assert 0 < meta["near"] < meta["far"]


def test_written_conventions_match_pycolmaps_projection(processed):
  """Every sparse point, projected with what transforms.json says (OpenGL pose, applied_transform,
  OPENCV lens), lands where pycolmap projects it with its own reconstruction; and the loaded,
  undistorted Dataset's pinhole camera sees it at the undistorted position."""
  root, _, _ = processed
  out = root / "out"
  model = pycolmap.Reconstruction(str(out / "colmap" / "sparse" / "0"))
  meta = json.loads((out / "transforms.json").read_text())
  applied = np.array(meta["applied_transform"])
  intrinsics = tuple(meta[k] for k in ("fl_x", "fl_y", "cx", "cy"))
  dist = tuple(meta[k] for k in ("k1", "k2", "p1", "p2"))
  dataset, names, _ = nerfstudio.load(str(out))
  checked = 0
  for image in model.images.values():
    k = names.index(f"images/{image.name}")
    c2w = np.array(meta["frames"][[f["file_path"] for f in meta["frames"]].index(
        f"images/{image.name}")]["transform_matrix"])
    ids = [p.point3D_id for p in image.points2D if p.has_point3D()]
    xyz = np.array([model.points3D[i].xyz for i in ids])
    want = np.array([image.project_point(p) for p in xyz])
    ours_world = xyz @ applied[:, :3].T + applied[:, 3]
    cam = (ours_world - c2w[:3, 3]) @ c2w[:3, :3]  # OpenGL camera space
    cam_cv = cam * [1.0, -1.0, -1.0]
    np.testing.assert_allclose(lens.project(cam_cv, intrinsics, dist), want, atol=1e-3)
    # The Dataset (undistorted at load, pixel_center = 0): pixel index of the pinhole projection.
    fx, fy, cx, cy = dataset.intrinsics
    pose = dataset.poses[k].astype(np.float64)
    cam = (ours_world - pose[:3, 3]) @ pose[:3, :3]
    pinhole = np.stack([fx * cam[:, 0] / -cam[:, 2] + cx, -fy * cam[:, 1] / -cam[:, 2] + cy], -1)
    undone = lens.undistort((want - intrinsics[2:]) / intrinsics[:2], dist)
    np.testing.assert_allclose(pinhole, undone * intrinsics[:2] + intrinsics[2:] - 0.5,
                               atol=1e-3)
    checked += len(ids)
  assert checked > 100


def test_too_few_registered_says_how_many(tmp_path):
  photos = tmp_path / "photos"
  _photograph(str(photos), 12)  # 30° apart: too little overlap for some pairs
  rng = np.random.default_rng(0)
  for k in range(4):  # and unrelated noise
    iio.imwrite(photos / f"noise_{k}.jpg", rng.integers(0, 256, (SIZE, SIZE, 3), np.uint8))
  with pytest.raises(sfm.SfmError) as info:
    process.process(str(tmp_path / "out"), images=str(photos), min_registered=0.9,
                    log=lambda _: None)
  message = str(info.value)
  found = re.search(r"only (\d+) of 16 images registered \(need 90%\)", message)
  assert "\n" not in message and found and int(found.group(1)) < 15 and "overlap" in message


def test_bad_inputs_give_one_line(tmp_path, monkeypatch):
  empty = tmp_path / "empty"
  empty.mkdir()
  quiet = lambda _: None
  assert_data_error(["--images=", "no images"], process.process, str(tmp_path / "o"),
                    images=str(empty), log=quiet)
  assert_data_error(["no such directory"], process.process, str(tmp_path / "o"),
                    images=str(tmp_path / "nope"), log=quiet)
  bad = tmp_path / "bad"
  bad.mkdir()
  iio.imwrite(bad / "a.jpg", np.zeros((8, 8, 3), np.uint8))
  (bad / "b.jpg").write_bytes(b"not a jpeg")
  assert_data_error(["b.jpg", "cannot read image"], process.process, str(tmp_path / "o"),
                    images=str(bad), log=quiet)
  (bad / "b.jpg").unlink()
  iio.imwrite(bad / "c.jpg", np.zeros((8, 16, 3), np.uint8))
  assert_data_error(["different sizes", "a.jpg is 8x8", "c.jpg is 16x8"], process.process,
                    str(tmp_path / "o"), images=str(bad), log=quiet)
  assert_data_error(["exactly one of"], process.process, str(tmp_path / "o"), log=quiet)
  monkeypatch.setitem(sys.modules, "pycolmap", None)  # `import pycolmap` raises ImportError
  assert_data_error(['pip install -e ".[capture]"'], process.process, str(tmp_path / "o"),
                    images=str(bad), log=quiet)


@pytest.mark.slow  # a process
def test_cli_exits_1_with_one_line(tmp_path):
  result = subprocess.run(
      [sys.executable, "-m", "nerf_jax.data.process", f"--images={tmp_path}",
       f"--out={tmp_path / 'o'}"], capture_output=True, text=True, timeout=120,
      env={**os.environ, "PYTHONPATH": ROOT}, cwd=ROOT)
  assert result.returncode == 1
  assert result.stderr.strip().splitlines() == [f"error: --images={tmp_path}: no images "
                                                "(.jpg, .jpeg, .png) found"]


def test_matcher_choice():
  # Unordered photos: every pair, whatever their count (no count switches to neighbours only).
  for count in (10, 100, 101, 500):
    matcher, why = sfm.choose_matcher("auto", count)
    assert matcher == "exhaustive" and f"every pair of the {count} matched" in why
    assert f"({count * (count - 1) // 2:,} pairs" in why and "\n" not in why
  # Neighbours only for an ordered capture: video frames, or photos the user says are in order.
  assert sfm.choose_matcher("auto", 500, video=True)[0] == "sequential"
  assert "video frames" in sfm.choose_matcher("auto", 10, video=True)[1]
  assert sfm.choose_matcher("auto", 10, ordered=True) == (
      "sequential", "--ordered: each photo matched with its neighbours in file-name order")
  # Asked for: as asked, whatever the capture.
  assert sfm.choose_matcher("exhaustive", 500, ordered=True, video=True) == (
      "exhaustive", "--matcher=exhaustive")
  assert sfm.choose_matcher("sequential", 5) == ("sequential", "--matcher=sequential")
  assert_data_error(["--matcher=vocab"], sfm.choose_matcher, "vocab", 10)


def test_the_matcher_and_why_are_one_logged_line(tmp_path, monkeypatch):
  photos = tmp_path / "photos"
  _photograph(str(photos), 4)
  asked = []

  def reconstruct(image_dir, work_dir, matcher, *args, **kwargs):  # SfM itself is tested above
    asked.append(matcher)
    return None, {}

  monkeypatch.setattr(sfm, "reconstruct", reconstruct)
  for options, matcher in (({}, "exhaustive"), ({"ordered": True}, "sequential")):
    lines = []
    with pytest.raises(sfm.SfmError, match="only 0 of 4 images registered") as info:
      process.process(str(tmp_path / "out"), images=str(photos), log=lines.append, **options)
    assert asked[-1] == matcher
    why = sfm.choose_matcher("auto", 4, **options)[1]
    assert f"      {matcher} matching: {why}" in lines
    # Exhaustive matching failed: sequential would not do better; sequential: try exhaustive.
    assert ("--matcher=exhaustive" in str(info.value)) == (matcher == "sequential")
    assert "--matcher=sequential" not in str(info.value)


def test_video_frames_are_sampled_evenly(tmp_path):
  frames = [np.full((16, 16, 3), 10 * k, np.uint8) for k in range(20)]
  iio.imwrite(tmp_path / "v.mp4", np.stack(frames), fps=10, codec="libx264",
              macro_block_size=1)
  out = tmp_path / "frames"
  out.mkdir()
  process.sample_video(str(tmp_path / "v.mp4"), 5, str(out))
  names = sorted(os.listdir(out))
  picked = [int(n[6:11]) for n in names]
  assert len(picked) == 5 and all(abs(k - j * 19 / 4) <= 0.5 for j, k in enumerate(picked))
  for name in names:  # each is the frame it is named after (grey level 10 k)
    k = int(name[6:11])
    assert abs(iio.imread(out / name).mean() - 10 * k) < 4
  assert_data_error(["--video=", "no such file"], process.sample_video,
                    str(tmp_path / "nope.mp4"), 5, str(out))


def test_video_in_posed_dataset_out(tmp_path):
  """The --video path end to end: a 48-frame orbit video, 24 frames sampled, sequential
  matching, a loadable dataset."""
  poses = [rays_lib.pose_spherical(theta, -30.0, 3.2) for theta in np.arange(0, 360, 7.5)]
  frames = [(capture_scene.render(p, SIZE, SIZE, (FOCAL, FOCAL, SIZE / 2, SIZE / 2)) * 255)
            .round().astype(np.uint8) for p in poses]
  iio.imwrite(tmp_path / "orbit.mp4", np.stack(frames), fps=24, codec="libx264", quality=9,
              macro_block_size=1)
  # One thread: COLMAP repeats itself exactly (with two, 18 of 24 registered once in CI).
  summary = process.process(str(tmp_path / "out"), video=str(tmp_path / "orbit.mp4"),
                            num_frames=24, log=lambda _: None, num_threads=1)
  assert summary["num_images"] == 24 and summary["num_registered"] >= 20
  train, test = nerfstudio.load_split(str(tmp_path / "out"))
  assert len(train) + len(test) == summary["num_registered"] and len(test) >= 3


def _random_poses(rng, num):
  """float64 [num, 4, 4] camera-to-world: random rotations, centres in a 4-unit box."""
  poses = np.tile(np.eye(4), (num, 1, 1))
  poses[:, :3, :3] = scipy.spatial.transform.Rotation.random(num, random_state=rng).as_matrix()
  poses[:, :3, 3] = rng.uniform(-2, 2, (num, 3))
  return poses


def _map(scale, rot, trans, poses):
  """Poses moved by x -> scale rot x + trans, the brute-force way: the 4x4 matrix product, then
  the rotation columns divided by the scale."""
  matrix = np.eye(4)
  matrix[:3, :3], matrix[:3, 3] = scale * rot, trans
  moved = matrix @ poses
  moved[:, :3, :3] /= scale
  return moved


def test_true_in_frame_inverts_the_alignment():
  """The true poses land in the SfM frame: exactly for an SfM frame that is a known similarity
  of the truth; with noisy SfM centres, by the inverse of the least-squares similarity SfM ->
  truth that a generic optimiser finds."""
  rng = np.random.default_rng(3)
  true = _random_poses(rng, 12)
  for scale, trans in ((0.37, [1.0, -2.0, 0.5]), (5.0, [0.0, 0.0, 0.0])):
    rot = scipy.spatial.transform.Rotation.random(random_state=rng).as_matrix()
    sfm_poses = _map(scale, rot, np.array(trans), true)  # SfM's frame: a similarity of the truth
    np.testing.assert_allclose(capture_bench.true_in_frame(sfm_poses, true), sfm_poses,
                               atol=1e-5 * max(scale, 1))
    rot_err, centre_err = capture_bench.pose_errors(sfm_poses, true)
    assert rot_err.max() < 1e-4 and centre_err.max() < 1e-9
  noisy = sfm_poses.copy()
  noisy[:, :3, 3] += rng.normal(0, 0.1, (12, 3))

  def residuals(x):  # SfM -> truth: scale exp(x[0]), rotation vector x[1:4], translation x[4:]
    r = scipy.spatial.transform.Rotation.from_rotvec(x[1:4]).as_matrix()
    return (np.exp(x[0]) * noisy[:, :3, 3] @ r.T + x[4:] - true[:, :3, 3]).ravel()

  fit = scipy.optimize.least_squares(residuals, np.zeros(7), xtol=1e-14, ftol=1e-14, gtol=1e-14)
  r = scipy.spatial.transform.Rotation.from_rotvec(fit.x[1:4]).as_matrix()
  s = np.exp(fit.x[0])
  want = _map(1 / s, r.T, -r.T @ fit.x[4:] / s, true)  # the inverse similarity, by hand
  np.testing.assert_allclose(capture_bench.true_in_frame(noisy, true), want, atol=2e-5)
  assert 0.02 < np.abs(want[:, :3, 3] - noisy[:, :3, 3]).max() < 0.5  # near SfM, not on it


def test_true_folder_differs_from_the_processed_one_only_in_poses(processed, tmp_path):
  """The true-pose folder loads the same images (resampled alike), camera, near/far and split as
  the processed one, at the true poses in the processed frame; with the true camera, the photos
  as they are."""
  root, truth, _ = processed
  out = str(root / "out")
  meta = json.loads((root / "out" / "transforms.json").read_text())
  true = truth[[int(f["file_path"][-6:-4]) for f in meta["frames"]]]
  written = capture_bench.write_true_folder(str(tmp_path / "true"), out, true)
  sfm_train, sfm_test = nerfstudio.load_split(out)
  true_train, true_test = nerfstudio.load_split(str(tmp_path / "true"))
  for a, b in ((sfm_train, true_train), (sfm_test, true_test)):
    np.testing.assert_array_equal(a.images, b.images)
    assert (a.intrinsics, a.near, a.far) == (b.intrinsics, b.near, b.far)
  sfm_poses = np.array([f["transform_matrix"] for f in meta["frames"]])  # file order = load order
  every_8th = np.arange(len(written)) % 8 == 0
  np.testing.assert_allclose(true_train.poses, written[~every_8th], atol=1e-6)
  np.testing.assert_allclose(true_test.poses, written[every_8th], atol=1e-6)
  distance = np.linalg.norm(sfm_poses[:, :3, 3], axis=-1)  # in the processed frame's units
  assert np.median(np.linalg.norm(written[:, :3, 3] - sfm_poses[:, :3, 3], axis=-1)
                   / distance) < 0.01
  cos = (np.einsum("nij,nij->n", written[:, :3, :3], sfm_poses[:, :3, :3]) - 1) / 2
  assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) < 0.5
  camera = {"fl_x": FOCAL, "fl_y": FOCAL, "cx": SIZE / 2, "cy": SIZE / 2}
  capture_bench.write_true_folder(str(tmp_path / "cam"), out, true, camera)
  cam_ds, names, _ = nerfstudio.load(str(tmp_path / "cam"))
  assert cam_ds.intrinsics == lens.dataset_intrinsics((FOCAL, FOCAL, SIZE / 2, SIZE / 2))
  np.testing.assert_allclose(cam_ds.images[3], iio.imread(root / "out" / names[3]) / 255.0,
                             atol=1e-6)


@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
def test_evaluate_at_scores_the_given_poses(trained_run):
  """At the run's own test views the score is the run's; with each camera tilted by 10° it
  drops."""
  workdir, result = trained_run
  test_ds = experiment.restore(str(workdir))[0].test_ds
  same = capture_bench.evaluate_at(str(workdir), test_ds)
  np.testing.assert_allclose(same["psnr"], result["psnr"], atol=1e-3)
  turn = np.eye(4, dtype=np.float32)
  turn[:3, :3] = scipy.spatial.transform.Rotation.from_euler("x", 10, degrees=True).as_matrix()
  moved = dataclasses.replace(test_ds, poses=test_ds.poses @ turn)  # about the camera's x axis
  assert capture_bench.evaluate_at(str(workdir), moved)["psnr"] < result["psnr"] - 1.0



# Photos from many cameras: (width, height, focal) of each, the principal point at the centre;
# the same field of view across, focal lengths 20-25% apart.
CAMERAS = ((128, 128, 160.0), (192, 144, 240.0), (128, 176, 200.0))


def _photograph_cameras(folder, num_views=NUM_VIEWS):
  """The ring of `_photograph` taken in turn by each of CAMERAS; returns each view's camera:
  int [num_views], an index into CAMERAS."""
  os.makedirs(folder, exist_ok=True)
  which = np.arange(num_views) % len(CAMERAS)
  for k, pose in enumerate(capture_scene.ring_poses(num_views)):
    width, height, focal = CAMERAS[which[k]]
    image = capture_scene.render(pose, height, width, (focal, focal, width / 2, height / 2))
    iio.imwrite(os.path.join(folder, f"view_{k:02d}.jpg"),
                (image * 255).round().astype(np.uint8), quality=95)
  return which


def test_photos_of_different_sizes_need_nosingle_camera(tmp_path):
  """--nosingle_camera poses photos of three sizes and focal lengths: each frame carries its own
  camera, the run's loader keeps each photo's size, and each recovered focal is its own."""
  which = _photograph_cameras(str(tmp_path / "photos"))
  assert_data_error(["different sizes", "--nosingle_camera"], process.process,
                    str(tmp_path / "out"), images=str(tmp_path / "photos"), log=lambda _: None)
  summary = process.process(str(tmp_path / "out"), images=str(tmp_path / "photos"),
                            single_camera=False, log=lambda _: None, num_threads=1)
  assert summary["num_registered"] == NUM_VIEWS
  meta = json.loads((tmp_path / "out" / "transforms.json").read_text())
  assert "fl_x" not in meta and "w" not in meta  # no shared camera: every frame has its own
  own = np.array([which[int(f["file_path"][-6:-4])] for f in meta["frames"]])
  truth = np.array([CAMERAS[c] for c in own])
  got = np.array([[f[k] for k in ("w", "h", "fl_x", "fl_y")] for f in meta["frames"]])
  np.testing.assert_array_equal(got[:, :2], truth[:, :2])
  assert all(k in f for f in meta["frames"] for k in ("cx", "cy", "k1", "k2", "p1", "p2"))
  # Each focal within 8% (128-pixel photos; at most 4% seen), each camera's median within 3%
  # (1.1% seen): a frame given another camera's focal would be 17% or more off.
  np.testing.assert_allclose(got[:, 2:], truth[:, 2:3].repeat(2, 1), rtol=0.08)
  medians = np.array([np.median(got[own == c, 2]) for c in range(len(CAMERAS))])
  focals = np.array([focal for _, _, focal in CAMERAS])
  np.testing.assert_allclose(medians / medians[0], focals / focals[0], rtol=0.03)
  data = config_lib.load("capture").data
  data.path = str(tmp_path / "out")
  train, test = load_data(data)  # as `train.py --config=capture` loads it
  for dataset in (train, test):
    sizes = [im.shape[:2] for im in dataset.images]
    assert sizes == list(zip(dataset.cameras.height, dataset.cameras.width))
  assert {s for d in (train, test) for s in zip(d.cameras.width, d.cameras.height)} == {
      (w, h) for w, h, _ in CAMERAS}


def test_writer_gives_each_frame_its_camera(tmp_path):
  """write_dataset of a Reconstruction with a camera per image (sizes, focals, principal points
  and distortion all differ) writes each frame's fields exactly, and the loader reads them."""
  rng = np.random.default_rng(0)
  names = [f"p{k}.jpg" for k in range(4)]
  sizes = np.array([[120, 160], [90, 120], [160, 160], [120, 160]])  # (height, width)
  intrinsics = np.column_stack([rng.uniform(100, 200, (4, 2)), sizes[:, ::-1] / 2 + 3])
  dist = np.column_stack([rng.uniform(-0.05, 0.05, (4, 2)), np.zeros((4, 2))])
  (tmp_path / "images").mkdir()
  for name, size in zip(names, sizes):
    iio.imwrite(tmp_path / "images" / name, np.full((*size, 3), 90, np.uint8))
  rec = sfm.Reconstruction(
      names=names, poses=np.asarray(capture_scene.ring_poses(4), np.float64),
      intrinsics=intrinsics, dist=dist, camera_ids=np.arange(4), size=tuple(sizes[0]),
      points=rng.uniform(-1, 1, (50, 3)), colors=np.zeros((50, 3), np.uint8),
      point_errors=np.zeros(50), mean_error=0.0, colmap=None, sizes=sizes)
  process.write_dataset(str(tmp_path), rec)
  frames = json.loads((tmp_path / "transforms.json").read_text())["frames"]
  for frame, k, d, (h, w) in zip(frames, intrinsics, dist, sizes):
    assert [frame[f] for f in ("fl_x", "fl_y", "cx", "cy")] == k.tolist()
    assert [frame[f] for f in ("k1", "k2", "p1", "p2")] == d.tolist()
    assert (frame["w"], frame["h"]) == (w, h)
  dataset, _, _ = nerfstudio.load(str(tmp_path))
  assert [im.shape[:2] for im in dataset.images] == [tuple(s) for s in sizes]
  np.testing.assert_allclose(dataset.cameras.fx, intrinsics[:, 0])
