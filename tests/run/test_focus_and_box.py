"""An unbounded capture's box under --config=auto: contraction where the training rays leave the
box (the share the run's warning reads, so the two never disagree), and the world centred on the
point the cameras look at (nerfstudio's 'focus'), with cameras generated here looking at an
off-centre point."""

import re

import numpy as np
import pytest

from nerf_jax.run import config_lib, experiment, from_data
from nerf_jax.run.auto import characterise
from nerf_jax.run.auto.rules import contraction

# auto's choices as on a CPU, also when the suite runs on a GPU (conftest.cpu_decisions).
pytestmark = pytest.mark.usefixtures("cpu_decisions")

TARGET = np.array([3.0, -1.5, 2.0])  # the point the cameras look at, off the origin


def _look_at(centre, target):
  """float64 [4, 4] camera-to-world of a camera at `centre` whose -z axis points at `target`,
  +y as near world +z as it can be (rays.py's axes)."""
  back = centre - target
  back /= np.linalg.norm(back)
  right = np.cross([0.0, 0.0, 1.0], back)
  right /= np.linalg.norm(right)
  pose = np.eye(4)
  pose[:3, :3] = np.stack([right, np.cross(back, right), back], axis=1)
  pose[:3, 3] = centre
  return pose


def _ring(num=12, aim_error=0.0, seed=0):
  """float64 [num, 4, 4]: cameras around TARGET at distances 2 to 5, above and below it, each
  aimed at TARGET plus a random offset of `aim_error` per axis."""
  rng = np.random.default_rng(seed)
  angles = np.linspace(0, 2 * np.pi, num, endpoint=False)
  distance = np.linspace(2.0, 5.0, num)
  height = 0.5 * np.sin(3 * angles)
  centres = TARGET + np.stack([np.cos(angles), np.sin(angles), height], 1) * distance[:, None]
  aims = TARGET + aim_error * rng.standard_normal((num, 3))
  return np.stack([_look_at(c, a) for c, a in zip(centres, aims)])


def test_the_axes_meet_where_the_cameras_look():
  poses = _ring()
  np.testing.assert_allclose(characterise.axes_meet(poses), TARGET, atol=1e-9)
  np.testing.assert_allclose(characterise.off_axis_sines(poses, TARGET), 0.0, atol=1e-6)
  assert characterise.focus(poses).found
  # Off-aim cameras: the least-squares point, written out here as the normal equations of
  # sum_n |(I - d_n d_n^T)(p - c_n)|^2, with d_n each camera's unit -z axis.
  poses = _ring(aim_error=0.3)
  dirs = -poses[:, :3, 2]
  proj = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
  want = np.linalg.solve(proj.sum(0), np.einsum("nij,nj->i", proj, poses[:, :3, 3]))
  point = characterise.axes_meet(poses)
  np.testing.assert_allclose(point, want, atol=1e-9)
  sines = characterise.off_axis_sines(poses, point)
  distance = np.linalg.norm(point - poses[:, :3, 3], axis=1)
  brute = [np.linalg.norm(np.cross(point - c, d)) / r  # |axis' distance from the point| / r
           for c, d, r in zip(poses[:, :3, 3], dirs, distance)]
  np.testing.assert_allclose(sines, brute, atol=1e-9)


def test_cameras_that_look_outwards_or_all_one_way_have_no_focus():
  outward = _ring()
  outward[:, :3, :3] = outward[:, :3, :3] @ np.diag([-1.0, 1.0, -1.0])  # turned about +y
  parallel = _ring()
  parallel[:, :3, :3] = np.eye(3)
  for poses in (outward, parallel):
    assert characterise.axes_meet(poses) is None
    assert not characterise.focus(poses).found


def test_cameras_that_miss_the_point_by_far_have_no_focus():
  assert not characterise.focus(_ring(aim_error=3.0, seed=1)).found


def _capture(tmp_path, far, num=12, size=8):
  """A tiny_nerf .npz of random RGB photos (no opacity) from `_ring`'s cameras, far bound
  `far`; its path."""
  rng = np.random.default_rng(0)
  path = tmp_path / "ring.npz"
  np.savez(path, images=rng.uniform(size=(num, size, size, 3)).astype(np.float32),
           poses=_ring(num).astype(np.float32), focal=np.float32(size), near=np.float32(0.5),
           far=np.float32(far), pixel_center=np.float32(0.5))
  return str(path)


def _auto(path):
  config = config_lib.load("auto")
  config.data.path = path
  return config


def test_auto_contracts_where_the_rays_leave_the_box_and_centres_on_the_focus(tmp_path, capsys):
  """far = 100 (walls, sky): nearly every ray leaves the cameras' box (±7 about the origin);
  auto contracts beyond it, centres the world on TARGET and sizes the inner region from the
  cameras' distances from it; the run's warning about rays leaving the box does not come."""
  exp = experiment.setup(_auto(_capture(tmp_path, far=100.0)))
  out = capsys.readouterr().out
  assert exp.config.data.contraction == contraction.CONTRACTION and exp.config.data.focus
  assert "leave the scene box" not in out  # the warning (from_data.warn_if_cut)
  decided = "\n".join(exp.config.auto_decisions)
  assert "the space beyond the box contracted (data.contraction='linf')" in decided
  assert "the inner region centred where the cameras look (data.focus)" in decided
  # The world moved by -TARGET: the cameras look at the origin, every pose and no rotation.
  ring = _ring()
  train = exp.train_ds.poses
  np.testing.assert_allclose(characterise.axes_meet(train), 0.0, atol=1e-4)
  for pose in train:
    k = np.argmin(np.abs(ring[:, :3, :3] - pose[:3, :3]).sum((1, 2)))
    np.testing.assert_allclose(pose[:3, 3], ring[k, :3, 3] - TARGET, atol=1e-5)
  # The inner box: the cameras' box about the focus, the farthest camera coordinate from it.
  want = np.max(np.abs(train[:, :3, 3]))
  assert exp.config.data.scene_bound == pytest.approx(want, abs=1e-3)
  assert exp.renderer.sampler.contraction == "linf"
  # Test views moved alike: their cameras look at the origin too.
  assert np.allclose(characterise.off_axis_sines(exp.test_ds.poses, np.zeros(3)), 0, atol=1e-5)


def test_auto_keeps_the_box_where_the_rays_stay_in_it(tmp_path, capsys):
  """far = 4.5: the rays end inside the cameras' box; no contraction, no move, no warning."""
  exp = experiment.setup(_auto(_capture(tmp_path, far=4.5)))
  out = capsys.readouterr().out
  assert not exp.config.data.contraction and not exp.config.data.focus
  assert "leave the scene box" not in out
  assert any(re.fullmatch(r"no contraction: [0-9]% of the training rays leave the box ±5.12 "
                          r"from the cameras' box before their far bound 4.5 \(<= 25%\)", l)
             for l in exp.config.auto_decisions), exp.config.auto_decisions


def test_the_warning_and_auto_read_one_share(tmp_path, capsys):
  """The same capture with the box kept (data.contraction='' given by the user, which auto
  leaves alone, centre included): the warning comes, with cut_share's share."""
  path = _capture(tmp_path, far=100.0)
  config = _auto(path)
  config.auto_flags = ("data.contraction",)
  exp = experiment.setup(config)
  out = capsys.readouterr().out
  assert not exp.config.data.contraction and not exp.config.data.focus
  bound = exp.config.data.scene_bound
  share = from_data.cut_share(exp.train_ds, bound, exp.near, exp.far, exp.pixel_center)
  assert share > 0.9
  assert f"note: {100 * share:.0f}% of training rays leave the scene box" in out
