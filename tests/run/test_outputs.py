"""What a run writes is read back and checked against an independent render: the video's frames
and size, the eval depth `.npy` files, TensorBoard's scalars against metrics.jsonl, and
`render.py --mode=views` from `.json` and [N, 3, 4] poses.

All read the shared trained run (conftest.py's trained_run). The independent path renders every ray
of a view in one `RayRenderer.render` call on rays from `rays.get_rays`, without the chunked
image renderer the outputs go through.
"""

import json

import imageio.v2 as imageio
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import camera_paths
from nerf_jax.render import background, renderer
from nerf_jax.run import experiment, outputs
from nerf_jax.evaluate.visuals import to_uint8
from nerf_jax.cameras.rays import Rays, get_rays
from tests.helpers import tensorboard_scalars
from tests.helpers import PATHS_RTOL, jitted, requires_ffmpeg


def _reference(exp, variables, pose):
  """numpy dict rgb [H, W, 3], depth [H, W] of `pose` through the training camera, all rays in
  one call (the debug config: the data's pixel centres, no NDC, no scene box)."""
  ds = exp.train_ds
  origins, directions = get_rays(ds.height, ds.width, ds.focal, jnp.asarray(pose),
                                 exp.pixel_center)
  rays = Rays.create(origins, directions, exp.near, exp.far)
  out = renderer.final(jitted(exp.renderer.render)(variables, rays))
  return {k: np.asarray(out[k]) for k in ("rgb", "depth", "acc")}


@pytest.fixture(scope="module")
def restored(trained_run):
  workdir, _ = trained_run
  exp, state = experiment.restore(str(workdir))
  return workdir, exp, state.variables


def test_eval_depth_npy_and_panels_hold_the_rendered_views(restored):
  workdir, exp, variables = restored
  for i, pose in enumerate(exp.test_ds.poses):
    ref = _reference(exp, variables, pose)
    depth = np.load(workdir / "eval" / f"depth_{i:03d}.npy")
    assert depth.dtype == np.float32 and depth.shape == ref["depth"].shape
    np.testing.assert_allclose(depth, ref["depth"], rtol=PATHS_RTOL, atol=1e-4)
    panel = imageio.imread(workdir / "eval" / f"view_{i:03d}.png")
    width = exp.test_ds.width
    assert panel.shape == (exp.test_ds.height, 3 * width, 3)
    diff = np.abs(panel[:, :width].astype(int) - to_uint8(ref["rgb"]).astype(int))
    assert diff.max() <= 1
    truth = background.images_on_background(
        exp.test_ds, background.parse(exp.config.data.background))[1][i]
    assert np.abs(panel[:, 2 * width:].astype(int) - to_uint8(truth)).max() == 0


def test_eval_geometry_scores_match_the_truth(restored):
  """metrics.json's depth error, empty-pixel opacity and floater fraction, recomputed per view
  from the independent render and the scene's exact depth and opacity."""
  workdir, exp, variables = restored
  per_view = json.loads((workdir / "eval" / "metrics.json").read_text())["per_view"]
  for i, pose in enumerate(exp.test_ds.poses):
    ref = _reference(exp, variables, pose)
    true_acc, true_depth = exp.test_ds.accs[i], exp.test_ds.depths[i]
    hit, empty = true_acc > 0.99, true_acc < 0.01
    assert hit.sum() > 20 and empty.sum() > 20  # the views score both kinds of pixel
    np.testing.assert_allclose(per_view[i]["depth_error"],
                               np.median(np.abs(ref["depth"] - true_depth)[hit]), atol=1e-4)
    np.testing.assert_allclose(per_view[i]["empty_opacity"], ref["acc"][empty].mean(), atol=1e-4)
    floaters = np.mean(ref["acc"][empty] > 0.1)
    assert abs(per_view[i]["floaters"] - floaters) <= 2 / empty.sum()  # a pixel at the edge


def _frames(path):
  with imageio.get_reader(str(path)) as reader:
    return np.stack([np.asarray(frame) for frame in reader])


@requires_ffmpeg
def test_video_has_the_configured_frames_and_size(restored):
  workdir, exp, variables = restored
  config = exp.config
  poses = camera_paths.video_poses(exp.train_ds, config.render.video_frames, config.data.ndc,
                                   config.render.orbit_phi, config.render.orbit_radius)
  rgb = _frames(workdir / "video" / "rgb.mp4")
  depth = _frames(workdir / "video" / "depth.mp4")
  size = (exp.train_ds.height, exp.train_ds.width, 3)
  assert rgb.shape == depth.shape == (config.render.video_frames, *size)
  # Each frame is its orbit pose's render (up to video compression), in order.
  refs = [to_uint8(_reference(exp, variables, pose)["rgb"]).astype(float) for pose in poses]
  for k, frame in enumerate(rgb.astype(float)):
    errors = [np.mean(np.abs(frame - ref)) for ref in refs]
    assert np.argmin(errors) == k and errors[k] < 8.0, errors  # uint8 units


@requires_ffmpeg
def test_path_mode_renders_a_video_through_the_key_cameras(restored, tmp_path):
  """render.py --mode=path: the viewer's camera_path.json key cameras, interpolated."""
  workdir, exp, variables = restored
  keys = exp.test_ds.poses[:2]
  path = tmp_path / "camera_path.json"
  path.write_text(json.dumps({"fps": 30, "keyframes": keys.tolist(), "frames": []}))
  outputs.render(str(workdir), "path", str(path), str(tmp_path / "path"), path_frames=3)
  rgb = _frames(tmp_path / "path" / "rgb.mp4")
  assert rgb.shape == (3 + 1, exp.train_ds.height, exp.train_ds.width, 3)  # 3 per segment + end
  # The path starts and ends at the key cameras (up to video compression).
  for frame, key in ((rgb[0], keys[0]), (rgb[-1], keys[1])):
    ref = to_uint8(_reference(exp, variables, key)["rgb"]).astype(float)
    assert np.mean(np.abs(frame.astype(float) - ref)) < 8.0  # uint8 units


def test_tensorboard_scalars_equal_the_json_log(restored):
  workdir, _, _ = restored
  scalars = tensorboard_scalars(workdir)
  records = [json.loads(l) for l in (workdir / "metrics.jsonl").read_text().splitlines()]
  evals = [(r["step"], r["eval_psnr"]) for r in records if "eval_psnr" in r and "final" not in r]
  assert [s for s, _ in evals] == [300, 600]
  assert [s for s, _ in scalars["eval/psnr"]] == [300, 600]
  for (_, logged), (_, board) in zip(evals, scalars["eval/psnr"]):
    assert board == pytest.approx(logged, rel=1e-6)  # TensorBoard stores float32
  final = [r for r in records if r.get("final")][-1]
  assert scalars["test/psnr"] == [(600, pytest.approx(final["eval_psnr"], rel=1e-6))]
  losses = [(r["step"], r["loss"]) for r in records if "loss" in r]
  assert [(s, pytest.approx(v, rel=1e-6)) for s, v in losses] == scalars["train/loss"]


def test_views_mode_reads_json_and_3x4_poses(restored, tmp_path):
  workdir, exp, variables = restored
  poses = exp.test_ds.poses[:2]
  json_path = tmp_path / "poses.json"
  json_path.write_text(json.dumps({"frames": [{"transform_matrix": p.tolist()} for p in poses]}))
  npy_path = tmp_path / "poses_3x4.npy"
  np.save(npy_path, poses[:, :3])
  for path in (json_path, npy_path):
    out_dir = tmp_path / path.stem
    outputs.render(str(workdir), "views", str(path), str(out_dir))
    for i, pose in enumerate(poses):
      ref = _reference(exp, variables, pose)
      image = imageio.imread(out_dir / f"view_{i:03d}.png")
      assert np.abs(image.astype(int) - to_uint8(ref["rgb"])).max() <= 1, path
      np.testing.assert_allclose(np.load(out_dir / f"depth_{i:03d}.npy"), ref["depth"],
                                 rtol=PATHS_RTOL, atol=1e-4)
    assert not (out_dir / "view_002.png").exists()
