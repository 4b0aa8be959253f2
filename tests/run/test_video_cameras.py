"""The video's cameras where the training images have their own (run/outputs.frame_cameras): each
frame takes the field of view of the nearest photo at the video's one frame size."""

import types

import numpy as np

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data.dataset import Dataset
from nerf_jax.run import outputs
from nerf_jax.run.experiment_parts import Experiment

# Photos of different sizes and zooms along x (a collection's cameras).
CAMERAS = [(48, 64, (70.0, 70.0, 32.0, 24.0)), (60, 40, (50.0, 52.0, 19.0, 31.0)),
           (40, 40, (120.0, 120.0, 20.0, 20.0))]


def at(x):
  """float32 [4, 4]: a camera at (x, 0, 4) looking down -z."""
  pose = np.eye(4, dtype=np.float32)
  pose[:3, 3] = (x, 0.0, 4.0)
  return pose


def experiment(cameras):
  """An object with Experiment's `camera` over a Dataset of `cameras` at x = 0, 1, 2."""
  images = [np.zeros((h, w, 3), np.float32) for h, w, _ in cameras]
  if len({(h, w) for h, w, _ in cameras}) == 1:
    images = np.stack(images)  # one size: an array, as the loaders give it
  poses = np.stack([at(float(x)) for x in range(len(cameras))])
  ds = Dataset(images=images, poses=poses, intrinsics=cameras[0][2],
               image_cameras=Cameras.stack(cameras), near=0.1, far=10.0)
  exp = types.SimpleNamespace(train_ds=ds)
  exp.camera = lambda scale=1.0: Experiment.camera(exp, scale)
  return exp


def vertical_fov(height, fy):
  return 2.0 * np.arctan(height / (2.0 * fy))


def test_each_frame_takes_its_nearest_photo_field_of_view():
  exp = experiment(CAMERAS)
  poses = np.stack([at(x) for x in (1.9, 0.2, 1.1, 2.4)])
  nearest = (2, 0, 1, 2)  # by camera centre, written out
  for scale in (1.0, 0.5):
    cams = outputs.frame_cameras(exp, poses, scale)
    height, width, (_, _, cx, cy) = exp.camera(scale)
    for (h, w, (fx, fy, px, py)), k in zip(cams, nearest):
      assert (h, w) == (height, width) and (px, py) == (cx, cy)  # one frame size, image 0's
      image_h, image_w, (kfx, kfy, _, _) = CAMERAS[k]
      np.testing.assert_allclose(vertical_fov(h, fy), vertical_fov(image_h, kfy), rtol=1e-6)
      np.testing.assert_allclose(fx / fy, kfx / kfy, rtol=1e-6)  # the photo's pixel aspect


def test_one_field_of_view_at_several_sizes_gives_the_training_camera():
  """Multiscale data: the same lens at full, half and quarter size."""
  full = (64, 64, (80.0, 80.0, 32.0, 32.0))
  scaled = [(64 // s, 64 // s, tuple(v / s for v in full[2])) for s in (1, 2, 4)]
  exp = experiment(scaled)
  cams = outputs.frame_cameras(exp, np.stack([at(x) for x in (0.1, 1.2, 2.3)]), 1.0)
  assert all(cam == exp.camera(1.0) for cam in cams)


def test_shared_cameras_need_none():
  exp = experiment([CAMERAS[0]] * 3)  # Dataset folds identical cameras into one
  assert exp.train_ds.image_cameras is None
  assert outputs.frame_cameras(exp, np.stack([at(0.0)]), 1.0) is None


def test_the_default_video_renders_through_the_frame_cameras(monkeypatch, tmp_path):
  """render_video hands the default path's frame cameras to render_frames, and poses given by a
  pose file keep the training camera."""
  exp = experiment(CAMERAS)
  exp.config = types.SimpleNamespace(
      render=types.SimpleNamespace(video_frames=3, orbit_phi=-30.0, orbit_radius=4.0, fps=2,
                                   video_path="orbit"),
      data=types.SimpleNamespace(ndc=False, contraction=False))
  exp.near, exp.far = 0.1, 10.0
  seen = []

  def fake_frames(exp_, variables, poses, scale=1.0, cameras=None):
    seen.append(cameras)
    for _ in poses:
      yield {"rgb": np.zeros((48, 64, 3), np.float32), "depth": np.ones((48, 64), np.float32)}

  monkeypatch.setattr(outputs, "render_frames", fake_frames)
  monkeypatch.setattr(outputs, "video_writer_missing", lambda: None)
  monkeypatch.setattr(outputs.imageio, "mimwrite", lambda *a, **k: None)
  outputs.render_video(exp, None, str(tmp_path), show_progress=False)
  poses = outputs.camera_paths.video_poses(exp.train_ds, 3, False, orbit_phi=-30.0,
                                           orbit_radius=4.0)
  assert seen[0] == outputs.frame_cameras(exp, poses, 1.0) and seen[0] is not None
  outputs.render_video(exp, None, str(tmp_path), show_progress=False, poses=poses)
  assert seen[1] is None
