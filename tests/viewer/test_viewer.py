"""The viewer's plain functions: camera conversion, resolution policy, cancellation, paths, and
a viewer camera at a training pose rendering what render.py renders (no browser needed)."""

import dataclasses
import logging
import math
import socket
import sys
import threading
import time

import imageio.v2 as imageio
import jax
import numpy as np
import pytest

from nerf_jax.cameras import camera_paths
from nerf_jax.render import image_renderer
from nerf_jax.run import builders, config_lib, experiment, outputs
from nerf_jax.cameras.rays import Rays, pose_spherical, project
from nerf_jax.cameras import keyframes
from nerf_jax.viewer import camera, policy, scene, server, training
from nerf_jax.evaluate.visuals import to_uint8
from tests.helpers import TINY_GRID, requires_viser, small_config


def _rodrigues(axis, angle):
  """Reference rotation matrix of `angle` radians about `axis`."""
  k = np.asarray(axis, np.float64) / np.linalg.norm(axis)
  kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
  return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


AXES_ANGLES = [((0, 0, 1), 0.0), ((1, 0, 0), 0.3), ((0, 1, 0), 2.0), ((1, 2, 3), math.pi - 1e-4),
               ((1, -1, 0.5), math.pi), ((0.2, 0.1, -1), 4.0)]


@pytest.mark.parametrize("axis,angle", AXES_ANGLES)
def test_quaternions_match_axis_angle(axis, angle):
  k = np.asarray(axis, np.float64) / np.linalg.norm(axis)
  q = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * k])
  np.testing.assert_allclose(camera.quaternion_to_matrix(q), _rodrigues(axis, angle), atol=1e-12)
  back = camera.matrix_to_quaternion(_rodrigues(axis, angle))
  assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9  # q and -q: one rotation


def _opencv_pixel(point, wxyz, position, f, cx, cy):
  """Brute-force OpenCV pinhole: camera looks down +z, pixel rows grow downwards (+y)."""
  cam = camera.quaternion_to_matrix(wxyz).T @ (np.asarray(point) - position)
  assert cam[2] > 0, "the point must be in front of the camera"
  return np.array([f * cam[0] / cam[2] + cx, f * cam[1] / cam[2] + cy])


@pytest.mark.parametrize("theta,phi,scale", [(0, -30, 1.0), (75, -10, 2.5), (200, -60, 0.1)])
def test_viewer_camera_sees_points_where_ours_does(theta, phi, scale):
  pose = pose_spherical(theta, phi, 4.0)
  wxyz, position = camera.c2w_to_viewer(pose, scale)
  np.testing.assert_allclose(camera.viewer_to_c2w(wxyz, position, scale), pose, atol=1e-6)
  np.testing.assert_allclose(position, pose[:3, 3] * scale, rtol=1e-6)
  f, size = 50.0, 64
  for point in np.random.default_rng(0).uniform(-1, 1, (8, 3)):
    ours = project(point, size, size, f, pose)  # (column, row) of our camera
    theirs = _opencv_pixel(point * scale, wxyz, position, f, size / 2, size / 2)
    np.testing.assert_allclose(theirs, ours, atol=1e-6)


def test_opencv_identity_is_our_camera_looking_down_world_z():
  c2w = camera.viewer_to_c2w((1, 0, 0, 0), (1, 2, 3))
  np.testing.assert_allclose(c2w[:3, 2], [0, 0, -1])  # we look down -z: the world's +z
  np.testing.assert_allclose(c2w[:3, 1], [0, -1, 0])  # OpenCV's y is down
  np.testing.assert_allclose(c2w[:3, 3], [1, 2, 3])


def test_frame_intrinsics_invert_vertical_fov():
  fov = camera.vertical_fov(100, 138.9)
  assert camera.frame_intrinsics(100, 150, fov) == pytest.approx((138.9, 138.9, 75.0, 50.0))
  assert camera.frame_size(48, 16 / 9) == (48, 85)


def _brute_height(rate, aspect, fps, overhead, max_height, ready=None):
  allowed = [h for h in policy.MOVING_HEIGHTS if (max_height is None or h <= max_height)
             and (ready is None or h in ready)]
  ok = [h for h in allowed if np.prod(camera.frame_size(h, aspect)) <= (1 / fps - overhead) * rate]
  return max(ok) if ok else min(allowed, default=policy.MOVING_HEIGHTS[0])


READY_SETS = [None, set(), {16}, {16, 24, 32, 48}, {24, 256}, set(policy.MOVING_HEIGHTS)]


@pytest.mark.parametrize("rate", [1e3, 5e4, 2.3e5, 1e6, 1e8])
@pytest.mark.parametrize("aspect,overhead,max_height", [(1.0, 0.0, None), (16 / 9, 0.02, 100)])
def test_moving_height_is_the_largest_ready_one_that_keeps_the_frame_rate(rate, aspect, overhead,
                                                                          max_height):
  for ready in READY_SETS:
    h = policy.moving_height(rate, aspect, 10.0, overhead, max_height, ready=ready)
    assert h == _brute_height(rate, aspect, 10.0, overhead, max_height, ready), ready
    if ready:
      assert h in ready or h > (max_height or math.inf)
    if h != min(ready or policy.MOVING_HEIGHTS):
      assert h * round(h * aspect) / rate + overhead <= 0.1


@pytest.mark.parametrize("aspect", [0.5, 1.0, 1000 / 600, 3.0])
def test_ready_heights_are_those_whose_frames_hold_few_enough_rays(aspect):
  for ready_rays in [0, 255, 256, 448, 1032, 30000, math.inf]:
    ready = policy.ready_heights(ready_rays, aspect)
    for h in policy.MOVING_HEIGHTS:
      height, width = camera.frame_size(h, aspect)
      assert (h in ready) == (height * width <= ready_rays)


def test_rate_meter_converges_to_a_steady_rate():
  meter = policy.RateMeter(rays_per_second=1.0, overhead_s=1.0)
  for _ in range(60):
    meter.add(20000, 0.1, 0.13)
  assert meter.rays_per_second == pytest.approx(2e5, rel=1e-6)
  assert meter.overhead_s == pytest.approx(0.03, rel=1e-6)


def _fake_draw(calls):
  def draw(rays, background=None):
    calls.append(len(rays.origins))
    return {"rgb": rays.origins + rays.directions, "depth": rays.viewdirs[:, 0],
            "acc": rays.origins[:, 1]}
  return draw


def test_render_in_chunks_equals_one_call_and_stops_when_cancelled():
  rng = np.random.default_rng(1)
  o, d, v = (rng.normal(size=(5, 7, 3)).astype(np.float32) for _ in range(3))
  rays = Rays(o, d, v, np.full((5, 7), 2.0, np.float32), np.full((5, 7), 6.0, np.float32))
  calls = []
  out = policy.render_in_chunks(_fake_draw(calls), rays, 8, (0, 0, 0))
  assert calls == [8, 8, 8, 8, 3]
  np.testing.assert_array_equal(out["rgb"], o + d)
  np.testing.assert_array_equal(out["depth"], v[..., 0])
  np.testing.assert_array_equal(out["acc"], o[..., 1])
  calls, checks = [], []
  cancel_after = lambda: checks.append(1) or len(checks) > 2  # the camera moves after 2 chunks
  assert policy.render_in_chunks(_fake_draw(calls), rays, 8, (0, 0, 0), cancel_after) is None
  assert calls == [8, 8]


def test_path_passes_through_key_cameras_and_turns_evenly():
  keys = np.stack([np.eye(4)] * 3)
  keys[1, :3, :3] = _rodrigues((0, 0, 1), math.pi / 2)
  keys[2, :3, :3] = _rodrigues((0, 0, 1), math.pi)
  keys[:, :3, 3] = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]  # evenly spaced on a line
  poses = keyframes.interpolate(keys, 4)
  assert poses.shape == (9, 4, 4)
  np.testing.assert_allclose(poses[::4], keys, atol=1e-6)
  for i, pose in enumerate(poses):
    np.testing.assert_allclose(pose[:3, :3], _rodrigues((0, 0, 1), i * math.pi / 8), atol=1e-6)
    np.testing.assert_allclose(pose[:3, 3], [i / 4, 0, 0], atol=1e-6)  # constant speed
  looped = keyframes.interpolate(keys, 4, loop=True)
  assert looped.shape == (12, 4, 4)
  np.testing.assert_allclose(looped[::4], keys, atol=1e-6)  # through the keys, then back
  np.testing.assert_allclose(looped[:9, :3, :3], poses[:, :3, :3], atol=1e-6)
  angle = lambda a, b: math.acos(np.clip((np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2, -1, 1))
  assert angle(looped[10], keys[2]) == pytest.approx(math.pi / 2, abs=1e-6)  # halfway home
  assert angle(looped[10], keys[0]) == pytest.approx(math.pi / 2, abs=1e-6)
  with pytest.raises(ValueError, match="at least 2"):
    keyframes.interpolate(keys[:1], 4)


def test_saved_path_is_what_render_py_loads(tmp_path):
  keys = np.stack([pose_spherical(th, -30, 4.0) for th in (0, 60, 150)])
  poses = keyframes.interpolate(keys, 5)
  json_path, npy_path = keyframes.save_path(str(tmp_path / "camera_path.json"), keys, poses, 24)
  np.testing.assert_allclose(camera_paths.load_poses(json_path), poses, atol=1e-6)
  np.testing.assert_array_equal(camera_paths.load_poses(npy_path), poses)
  rot = poses[:, :3, :3]
  np.testing.assert_allclose(rot @ np.swapaxes(rot, 1, 2), np.broadcast_to(np.eye(3), rot.shape),
                             atol=1e-5)


def test_depth_output_names_its_range():
  depth = np.linspace(2.0, 4.0, 100, dtype=np.float32).reshape(10, 10)
  acc = np.ones_like(depth)
  acc[:, :5] = 0.0  # misses: not part of the range
  lo, hi = server.depth_range(depth, acc, 1.0, 9.0)
  hits = depth[:, 5:]
  assert (lo, hi) == pytest.approx(tuple(np.percentile(hits, [2, 98])))
  image, caption = server.output_image({"depth": depth, "acc": acc, "rgb": None}, "Depth", 1, 9)
  assert image.shape == (10, 10, 3) and f"{lo:.3g}" in caption and f"{hi:.3g}" in caption
  assert server.depth_range(depth, np.zeros_like(acc), 1.0, 9.0) == (1.0, 9.0)
  opacity, _ = server.output_image({"depth": depth, "acc": acc, "rgb": None}, "Opacity", 1, 9)
  np.testing.assert_array_equal(opacity[..., 0], to_uint8(acc))


def test_port_taken_names_it_and_suggests_a_free_one():
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    s.listen()
    port = s.getsockname()[1]
    with pytest.raises(server.ViewerError) as info:
      server.check_port("127.0.0.1", port)
  message = str(info.value)
  assert f"port {port}" in message and "--port=" in message and "\n" not in message
  suggested = int(message.split("--port=")[1])
  assert suggested != port and server.port_free("127.0.0.1", suggested)


def test_missing_viser_says_which_extra(monkeypatch):
  monkeypatch.setitem(sys.modules, "viser", None)  # import viser now raises ImportError
  with pytest.raises(server.ViewerError, match=r'pip install -e "\.\[viewer\]"'):
    server.import_viser()


def test_workdir_without_checkpoint_is_one_line(tmp_path):
  with pytest.raises(FileNotFoundError, match="no such directory"):
    scene.from_workdir(str(tmp_path / "missing"))
  with pytest.raises(config_lib.ConfigError, match="config.json not found"):
    scene.from_workdir(str(tmp_path))


# A tiny marching fast-config model (its skip grid: 16^3 cells × 64 probes, not 48^3), drawn in
# chunks of 128 rays: the warm-up test below counts the sizes it compiles up to a chunk.
TINY_FAST = {**TINY_GRID, "render.chunk": 128}


@pytest.fixture(scope="module")
def tiny_run():
  """(experiment, its viewer Scene, random variables) of a tiny marching fast-config model."""
  exp = experiment.setup(small_config(TINY_FAST, base="fast"))
  init = jax.jit(exp.renderer.init)  # one compile, not one per eager operation
  return exp, scene.from_run(exp), init(jax.random.PRNGKey(3))


def test_viewer_camera_at_a_training_pose_renders_what_render_py_does(tmp_path, tiny_run):
  exp, view, variables = tiny_run
  train_ds = exp.train_ds
  pose = train_ds.poses[1]
  outputs.render_views(exp, variables, pose[None], str(tmp_path))

  wxyz, position = camera.c2w_to_viewer(pose, 2.0)  # what the browser's camera holds
  out = view.render(view.make_draw(variables), camera.viewer_to_c2w(wxyz, position, 2.0),
                    train_ds.height, train_ds.width, view.fov())
  expected_depth = np.load(tmp_path / "depth_000.npy")
  assert np.ptp(expected_depth) > 0.01  # not a blank image
  np.testing.assert_allclose(out["depth"], expected_depth, atol=1e-4)
  rgb = to_uint8(out["rgb"]).astype(int)
  assert np.abs(rgb - imageio.imread(tmp_path / "view_000.png").astype(int)).max() <= 1


class _FakeViewer:
  def __init__(self):
    self.watching, self.received = False, []

  def watched(self):
    return self.watching

  def set_params(self, params, step):
    self.received.append((params, step))


def test_training_hook_copies_params_only_while_watched_and_at_most_every_refresh():
  viewer, now = _FakeViewer(), [0.0]
  hook = training.LiveViewer(viewer, refresh_s=1.0, clock=lambda: now[0])
  calls = []
  params = {"w": jax.numpy.arange(3.0)}
  get = lambda: calls.append(1) or params
  for step in range(5):
    hook.after_step(step, get)
  assert not calls and not viewer.received  # nobody watching: nothing is copied
  viewer.watching = True
  for step in range(5, 30):
    now[0] = 0.25 * step
    hook.after_step(step, get)
  assert [s for _, s in viewer.received] == [5, 9, 13, 17, 21, 25, 29]  # every 4th step = 1 s
  sent = viewer.received[0][0]["w"]
  assert sent is not params["w"]
  np.testing.assert_array_equal(sent, params["w"])


def test_scene_box_edges_are_the_cube_edges():
  edges = server.box_edges(1.5)
  assert edges.shape == (12, 2, 3)
  delta = np.abs(edges[:, 1] - edges[:, 0])
  np.testing.assert_allclose(np.sort(delta, axis=1), np.broadcast_to([0, 0, 3.0], (12, 3)))
  assert np.all(np.abs(edges) == 1.5)
  assert len({tuple(sorted(map(tuple, e))) for e in edges}) == 12  # no edge twice


def _compiled(caplog, fn):
  """The names of the functions XLA compiled while fn() ran (jax.log_compiles' records)."""
  caplog.clear()
  with caplog.at_level(logging.WARNING), jax.log_compiles():
    fn()
  return [r.getMessage().split()[1] for r in caplog.records
          if r.getMessage().startswith("Compiling ")]


def test_after_each_compile_step_frames_of_the_ready_size_compile_nothing(tiny_run, caplog):
  exp, view, variables = tiny_run
  # Every cell kept (march_threshold 0): rounds select all the samples they can.
  config = small_config(TINY_FAST, base="fast", **{"render.march_threshold": 0.0})
  view = dataclasses.replace(  # and a renderer of its own, nothing compiled
      view, config=config, make_draw=image_renderer.make_image_renderer(
          exp.renderer, builders.image_settings(config)))
  draw = view.make_draw(variables)
  # Inside a narrow view of the box every sample of every ray is in it (see Sampler.bounds).
  pose, fov = np.eye(4, dtype=np.float32), 0.3
  pose[2, 3] = 3.4
  frame = lambda h, w: lambda: view.render(draw, pose, h, w, fov)
  readies, compiled, steps = [], [], view.compile_steps(draw)
  while True:
    compiled += _compiled(caplog, lambda: readies.append(next(steps, None)))
    if readies[-1] is None:
      break
    if readies[-1] == 64:  # the 1024-sample buffer: rounds of 64 rays × 16 samples
      assert _compiled(caplog, frame(8, 8)) == []
      assert "jit(query_round)" in _compiled(caplog, frame(5, 13))  # 65 rays need the next
  readies.pop()
  assert readies == [0, 64, math.inf]
  assert "jit(query_round)" in compiled and "jit(plan)" in compiled
  frames = lambda: [view.render(draw, pose, h, w, fov)
                    for h, w in [(16, 27), (23, 41), (20, 20), (7, 60), (48, 13)]]
  assert _compiled(caplog, frames) == []  # any size, any aspect: nothing new


class _FakeClient:
  """A browser for the server: a camera (wxyz, position, fov, canvas size) and the frames it
  was sent."""

  def __init__(self, pose, fov, width=1000, height=600):
    cam = type("Camera", (), {"on_update": lambda self, fn: None})()
    cam.wxyz, cam.position = camera.c2w_to_viewer(pose)
    cam.fov, cam.image_width, cam.image_height = fov, width, height
    self.frames = []
    sink = lambda image, **_: self.frames.append(image)
    self.camera, self.client_id = cam, 1
    self.scene = type("Scene", (), {"set_background_image": staticmethod(sink)})()


def _until(condition, seconds, what):
  end = time.time() + seconds
  while not condition():
    assert time.time() < end, f"timed out after {seconds} s waiting for {what}"
    time.sleep(0.02)


@pytest.mark.slow  # a server's threads, timed against the wall clock
@requires_viser
def test_server_sends_frames_of_ready_heights_before_the_warm_up_ends(tiny_run, monkeypatch):
  _, view, variables = tiny_run
  aspect, real_steps, gate, waited = 1000 / 600, view.compile_steps, threading.Event(), []
  ready_rays = int(np.prod(camera.frame_size(24, aspect)))  # 16 and 24 px frames are ready

  def slow_steps(draw):  # a warm-up stuck at heights <= 24 until the gate opens
    while not gate.is_set():
      time.sleep(0.05)
      waited.append(1)
      yield ready_rays
    yield from real_steps(draw)
  monkeypatch.setattr(view, "compile_steps", slow_steps)
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
  viewer = server.Viewer(view, variables, port=port, still_height=64)
  try:  # Viewer() returned (the command prints the address now) with the warm-up running
    assert not viewer.warmed.is_set()
    _until(lambda: viewer.ready_rays == ready_rays, 30, "the first warm-up step")
    client = _FakeClient(view.poses[0], view.fov())
    viewer._connect(client)  # pylint: disable=protected-access
    _until(lambda: len(client.frames) >= 2, 60, "a moving and a still frame")
    assert not viewer.warmed.is_set() and waited
    (_, w1, h1, moving1, _), (_, w2, h2, moving2, _) = viewer.frame_log[:2]
    # The policy would pick a larger height at the meter's initial rate; 24 is the largest ready.
    assert policy.moving_height(viewer.meter.rays_per_second, aspect, 10.0, 0.01, 64) > 24
    assert (moving1, h1, w1) == (True, *camera.frame_size(24, aspect))
    assert (moving2, h2, w2) == (False, *camera.frame_size(64, aspect))
    assert client.frames[0].shape == (h1, w1, 3) and client.frames[1].shape == (h2, w2, 3)
    gate.set()
    assert viewer.warmed.wait(60) and viewer.ready_rays == math.inf and viewer.warm_s > 0
  finally:
    viewer.close()


class _Recorder:
  """A stand-in for viser's scene and initial camera: records the frustums added."""

  def __init__(self):
    self.frustums = []

  def set_up_direction(self, up):
    del up

  def add_line_segments(self, *args, **kwargs):
    del args, kwargs

  def add_camera_frustum(self, name, fov, aspect, **kwargs):
    del kwargs
    self.frustums.append((name, fov, aspect))
    return type("Frustum", (), {"on_click": lambda self, fn: None})()


def test_each_training_camera_is_drawn_with_its_own_field_of_view_and_shape():
  from nerf_jax.cameras.cameras import Cameras  # pylint: disable=import-outside-toplevel
  # Two images of mip-NeRF's multiscale kind (full and half size, focal halved: one field of
  # view), and a third zoomed in at the first's size: vertical fields of view 2·atan(h / 2fy).
  cams = Cameras(fx=np.array([100.0, 50.0, 300.0]), fy=np.array([100.0, 50.0, 300.0]),
                 cx=np.array([80.0, 40.0, 80.0]), cy=np.array([60.0, 30.0, 60.0]),
                 width=np.array([160, 80, 160]), height=np.array([120, 60, 120]))
  poses = np.stack([pose_spherical(a, -30.0, 4.0) for a in (0.0, 90.0, 180.0)])
  data = type("Data", (), {"poses": poses, "cameras": cams, "height": 120, "width": 160,
                           "intrinsics": (100.0, 100.0, 80.0, 60.0)})()
  config = small_config(TINY_GRID, base="fast")
  view = scene.Scene(config, None, data, 2.0, 6.0, np.zeros(3, np.float32))
  viewer = server.Viewer.__new__(server.Viewer)
  recorder, initial = _Recorder(), type("Camera", (), {})()
  viewer.server = type("Server", (), {"scene": recorder, "initial_camera": initial})()
  viewer.scene, viewer.scale = view, 1.0
  viewer._add_scene()  # pylint: disable=protected-access
  want = [2.0 * math.atan(60.0 / 100.0), 2.0 * math.atan(30.0 / 50.0),
          2.0 * math.atan(60.0 / 300.0)]
  got = [f for f in recorder.frustums if f[0].startswith("/cameras/")]
  np.testing.assert_allclose([f[1] for f in got], want, rtol=1e-6)
  np.testing.assert_allclose([f[2] for f in got], [4.0 / 3.0] * 3, rtol=1e-6)
  assert initial.fov == pytest.approx(want[0])
