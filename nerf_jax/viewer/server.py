"""The viewer's page (viser) and its render loop.

One thread renders for every connected browser: while a browser's camera moves, frames of the
height `policy.moving_height` picks for `target_fps`; once it stops, one still frame at
`still_height` (default: the training images' height), cancelled between chunks by the next
camera move. Frames go to the page as its background image, under the training cameras'
frustums (click one to jump to it) and the scene box.

The page is served at once; a second thread compiles the renderer's shapes meanwhile
(Scene.compile_steps, smallest first, whenever no frame is due), and until it is done moving
frames only take the heights whose frames compile nothing (`ready_rays`). One lock lets one
render or one compile step run at a time.
"""

import math
import os
import socket
import threading
import time

import numpy as np

from nerf_jax.cameras import keyframes
from nerf_jax.run.settings import ViewerSettings
from nerf_jax.viewer import camera, policy
from nerf_jax.viewer.scene import colorize, to_uint8

OUTPUTS = ("RGB", "Depth", "Opacity")
INSTALL_HINT = 'pip install -e ".[viewer]"'


class ViewerError(ValueError):
  """The viewer cannot start; the one-line message says why and what to do (a ValueError, so
  nerf-view and nerf-train print it as one line)."""


def import_viser():
  """The viser module, or a ViewerError saying which extra installs it."""
  try:
    import viser  # pylint: disable=import-outside-toplevel
  except ImportError as e:
    raise ViewerError(f"the viewer needs the 'viewer' extra (viser): {INSTALL_HINT}") from e
  return viser


def port_free(host, port):
  """Whether a server can listen on `host`:`port` now."""
  with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's servers do
    try:
      s.bind((host, port))
    except OSError:
      return False
  return True


def check_port(host, port):
  """ViewerError naming the port and a free one to use instead, when `port` is taken."""
  if port_free(host, port):
    return
  free = next((p for p in range(port + 1, port + 100) if port_free(host, p)), None)
  hint = f"; try --port={free}" if free else ""
  raise ViewerError(f"port {port} on {host} is taken (another viewer or program){hint}")


def box_edges(half):
  """The 12 edges of the cube [-half, half]^3: float32 [12, 2, 3] (segment end points)."""
  corners = np.array([[x, y, z] for x in (-half, half) for y in (-half, half)
                      for z in (-half, half)], np.float32)
  pairs = [(i, j) for i in range(8) for j in range(i + 1, 8)
           if np.sum(corners[i] != corners[j]) == 1]  # corners differing in one coordinate
  return np.stack([corners[[i, j]] for i, j in pairs])


def depth_range(depth, acc, near, far):
  """(lo, hi): the 2nd and 98th percentile depth of the rays that hit something (acc > 0.5),
  or (near, far) when none does. depth, acc: float32 [H, W]."""
  hits = depth[acc > 0.5]
  if hits.size == 0:
    return near, far
  lo, hi = np.percentile(hits, [2.0, 98.0])
  return float(lo), float(max(hi, lo + 1e-6))  # a flat frame still gets a non-empty range


def output_image(out, output, near, far):
  """(uint8 [H, W, 3], caption) of one rendered frame for `output` in OUTPUTS."""
  if output == "Depth":
    lo, hi = depth_range(out["depth"], out["acc"], near, far)
    return colorize(out["depth"], lo, hi), f"depth {lo:.3g} (dark) to {hi:.3g} (bright)"
  if output == "Opacity":
    return to_uint8(np.repeat(out["acc"][..., None], 3, axis=-1)), "opacity 0 (black) to 1"
  return to_uint8(out["rgb"]), "rgb"


class _View:
  """One browser: its camera moves (`version`), what was drawn for which version."""

  def __init__(self, client):
    self.client = client
    self.version = 0  # camera updates received
    self.drawn = -1  # camera version of the newest frame sent
    self.still = False  # a full-resolution frame of `drawn` was sent

  def snapshot(self):
    """(version, c2w-ready camera: wxyz [4], position [3], fov, aspect)."""
    cam = self.client.camera
    return self.version, (np.array(cam.wxyz), np.array(cam.position), float(cam.fov),
                          cam.image_width / max(cam.image_height, 1))


class Viewer:
  """A viser server showing `scene` drawn with `params` (None: nothing until `set_params`);
  `set_params` swaps in new ones.

  target_fps: frames per second to hold while the camera moves. still_height: pixels of the
  full-resolution frame (None = the training images'). out_dir: where 'Save path' writes.
  scale: the viewer's world is ours times `scale`. warm_up: compile the renderer in the
  background, then time it on the first training camera (off while training: it would take
  time from the steps; frames then compile what they need when they need it).
  """

  def __init__(self, scene, params, host="127.0.0.1", port=ViewerSettings.port, step=None,
               target_fps=10.0, still_height=None, out_dir=".", scale=1.0, label="nerf_jax",
               warm_up=True):
    viser = import_viser()
    check_port(host, port)
    self.server = viser.ViserServer(host=host, port=port, label=label, verbose=False)
    if self.server.get_port() != port:  # taken between the check and the bind
      self.server.stop()
      raise ViewerError(f"port {port} on {host} is taken; try --port={port + 1}")
    self.scene, self.scale, self.target_fps = scene, scale, target_fps
    self.still_height = still_height or scene.height
    self.out_dir, self.host, self.port = out_dir, host, port
    self.meter = policy.RateMeter()
    self.frames_sent, self.last_frame, self.last_info = 0, None, ""
    self.frame_log = []  # (time sent, width, height, moving, seconds) of every frame
    self._lock = threading.Lock()  # the params, and the render loop's idle state
    self._render_lock = threading.Lock()  # one render or compile step at a time
    self._params, self._step, self._params_version, self._bound = params, step, 0, (-1, None)
    self._views, self._keyframes = {}, []
    self._wake, self._closing = threading.Event(), False
    self._idle = threading.Event()  # no frame is due: the warm-up may compile
    self._idle.set()
    # Frames of at most this many rays compile nothing (see policy.ready_heights).
    self.ready_rays = 0 if warm_up else math.inf
    self.warmed = threading.Event()  # every frame size compiled and the meter seeded
    self.warm_s = None  # seconds from the start of the warm-up to `warmed`
    self._add_scene()
    self._add_gui()
    self.server.on_client_connect(self._connect)
    self.server.on_client_disconnect(self._disconnect)
    self._threads = [threading.Thread(target=self._loop, name="viewer-render", daemon=True)]
    if warm_up:
      self._threads.append(threading.Thread(target=self._warm_up, name="viewer-warm-up",
                                            daemon=True))
    else:
      self.warmed.set()
    for thread in self._threads:
      thread.start()

  @property
  def url(self):
    host = "localhost" if self.host in ("0.0.0.0", "127.0.0.1") else self.host
    return f"http://{host}:{self.port}"

  def watched(self):
    """Whether a browser is connected."""
    return bool(self._views)

  def set_params(self, params, step=None):
    """Draw from `params` from now on (they must not be donated or changed afterwards)."""
    with self._lock:
      self._params, self._step = params, step
      self._params_version += 1
    self._wake.set()

  def close(self):
    self._closing = True
    self._wake.set()
    self._idle.set()
    for thread in self._threads:
      thread.join(timeout=10)
    self.server.stop()

  # The page.

  def _add_scene(self):
    sc, scene = self.server.scene, self.scene
    up = np.mean(scene.poses[:, :3, 1], axis=0)  # the training cameras' mean up direction
    up = up / max(np.linalg.norm(up), 1e-9)  # cameras whose ups cancel out: keep it finite
    sc.set_up_direction(tuple(float(u) for u in up))
    positions = scene.poses[:, :3, 3] * self.scale
    size = 0.08 * float(np.median(np.linalg.norm(positions - positions.mean(0), axis=1)) or 1.0)
    views = scene.camera_views()  # each image's own field of view and shape
    for i, (pose, (fov, aspect)) in enumerate(zip(scene.poses, views)):
      # No thumbnails: seen from a camera's apex they would cover the view.
      wxyz, position = camera.c2w_to_viewer(pose, self.scale)
      frustum = sc.add_camera_frustum(
          f"/cameras/{i}", fov=fov, aspect=aspect, scale=size, wxyz=wxyz, position=position,
          thickness=1.5, thickness_units="screen", color=(60, 110, 230))
      frustum.on_click(self._jump_to(wxyz, position, fov))
    if scene.scene_bound > 0:  # lines, not add_box: a box mesh hides the background image
      sc.add_line_segments("/scene_box", box_edges(scene.scene_bound * self.scale),
                           (255, 150, 0), thickness=1.5, thickness_units="screen")
    wxyz, position = camera.c2w_to_viewer(scene.poses[0], self.scale)
    forward = camera.quaternion_to_matrix(wxyz)[:, 2]
    reach = max(float(np.dot(-position, forward)), 0.1 * self.scale)  # nearest to the origin
    look_at = position + reach * forward
    initial = self.server.initial_camera  # behind the first training camera, looking past it
    initial.position, initial.look_at = look_at + 1.3 * (position - look_at), look_at
    initial.up, initial.fov = up, views[0][0]

  def _jump_to(self, wxyz, position, fov):
    def jump(event):
      cam = event.client.camera
      with event.client.atomic():
        cam.fov = fov
        cam.wxyz = wxyz
        cam.position = position
    return jump

  def _add_gui(self):
    gui = self.server.gui
    gui.add_markdown("**nerf_jax viewer**: drag to orbit, right-drag to pan, scroll to zoom; "
                     "click a camera to jump to it.")
    self.gui_output = gui.add_dropdown("Output", OUTPUTS, initial_value="RGB")
    self.gui_output.on_update(lambda _: self._redraw())
    self.gui_frame = gui.add_text("Frame", initial_value="waiting for a browser", disabled=True)
    self.gui_range = gui.add_text("Shows", initial_value="rgb", disabled=True)
    self.gui_step = gui.add_text("Step", initial_value=str(self._step), disabled=True)
    with gui.add_folder("Camera path"):
      add = gui.add_button("Add key camera")
      self.gui_keys = gui.add_text("Key cameras", initial_value="0", disabled=True)
      self.gui_per_segment = gui.add_number("Frames per segment", initial_value=30, min=1,
                                            step=1)
      self.gui_loop = gui.add_checkbox("Loop", initial_value=False)
      save = gui.add_button("Save path")
      clear = gui.add_button("Clear key cameras")
      self.gui_saved = gui.add_text("Saved", initial_value="", disabled=True)
    add.on_click(lambda event: self.add_keyframe(event.client))
    save.on_click(lambda _: self.save_path())
    clear.on_click(lambda _: self._set_keyframes([]))

  def add_keyframe(self, client):
    _, (wxyz, position, _, _) = _View(client).snapshot()
    self._set_keyframes(self._keyframes + [camera.viewer_to_c2w(wxyz, position, self.scale)])

  def _set_keyframes(self, keyframes):
    self._keyframes = keyframes
    self.gui_keys.value = str(len(keyframes))

  def save_path(self):
    """Interpolate the key cameras and write camera_path.json/.npy into out_dir."""
    if len(self._keyframes) < 2:
      self.gui_saved.value = "add at least 2 key cameras"
      return None
    poses = keyframes.interpolate(np.stack(self._keyframes), int(self.gui_per_segment.value),
                              bool(self.gui_loop.value))
    path = os.path.join(self.out_dir, "camera_path.json")
    keyframes.save_path(path, np.stack(self._keyframes), poses, self.scene.config.render.fps)
    self.gui_saved.value = f"{len(poses)} poses: render.py --mode=views --poses={path}"
    return path

  # Browsers.

  def _connect(self, client):
    view = _View(client)
    client.camera.on_update(lambda _: self._moved(view))
    self._views[client.client_id] = view
    self._frame_due()

  def _disconnect(self, client):
    self._views.pop(client.client_id, None)
    self._wake.set()

  def _moved(self, view):
    view.version += 1
    self._frame_due()

  def _redraw(self):
    for view in list(self._views.values()):
      view.still = False
    self._frame_due()

  def _frame_due(self):
    """Wake the render loop; the warm-up waits until it has drawn what is due."""
    with self._lock:
      self._idle.clear()
      self._wake.set()

  # Rendering.

  def _draw(self):
    """The draw function of the newest params (bound again when they change; call it holding
    the render lock: binding computes the skip grid)."""
    with self._lock:
      version, params, step = self._params_version, self._params, self._step
    if self._bound[0] != version:
      self._bound = (version, None if params is None else self.scene.make_draw(params))
      self.gui_step.value = str(step)
      if version > 0:
        self._redraw()
    return self._bound[1]

  def _warm_up(self):
    """Compile what frames need, a step at a time while no frame is due, raising `ready_rays`
    after each; then seed the render-rate meter."""
    start, steps, ready = time.perf_counter(), None, 0
    try:
      while not self._closing and ready is not None:
        if not self._idle.wait(timeout=0.5):
          continue  # frames first
        with self._render_lock:
          draw = self._draw()
          if draw is not None:
            steps = steps or self.scene.compile_steps(draw)
            ready = next(steps, None)
        if draw is None:
          time.sleep(0.5)  # no params yet
        elif ready is not None:
          self.ready_rays = ready
      self._seed_meter()
    finally:
      self.ready_rays = math.inf  # if a step failed, frames compile what they need
      self.warm_s = time.perf_counter() - start
      self.warmed.set()

  def _seed_meter(self):
    """Time a still frame of the first training camera, once no frame is due."""
    while not (self._closing or self._idle.wait(timeout=0.5)):
      pass
    if self._closing:
      return
    height, width = camera.frame_size(self.still_height, self.scene.width / self.scene.height)
    with self._render_lock:
      draw, start = self._draw(), time.perf_counter()
      self.scene.render(draw, self.scene.poses[0], height, width, self.scene.fov())
      self.meter.rays_per_second = height * width / (time.perf_counter() - start)

  def _loop(self):
    while not self._closing:
      self._wake.wait(timeout=0.5)
      self._wake.clear()
      with self._render_lock:
        draw = self._draw()
      for view in list(self._views.values()) if draw is not None else ():
        if self._closing:
          break
        version, cam = view.snapshot()
        if version != view.drawn:
          self._show(view, draw, cam, moving=True)
          view.drawn, view.still = version, False
          self._wake.set()  # next: refine, unless the camera moves on
        elif not view.still:
          done = self._show(view, draw, cam, moving=False,
                            cancelled=lambda v=view, n=version: v.version != n or self._closing)
          view.still = done
          if not done:
            self._wake.set()
      with self._lock:
        if not self._wake.is_set():  # everything due is drawn
          self._idle.set()

  def frame_height(self, moving, aspect):
    """Pixels per column of the next frame (see policy.moving_height)."""
    if not moving:
      return self.still_height
    return policy.moving_height(self.meter.rays_per_second, aspect, self.target_fps,
                                self.meter.overhead_s, max_height=self.still_height,
                                ready=policy.ready_heights(self.ready_rays, aspect))

  def _show(self, view, draw, cam, moving, cancelled=None):
    """Render and send one frame; False when cancelled."""
    wxyz, position, fov, aspect = cam
    height, width = camera.frame_size(self.frame_height(moving, aspect), aspect)
    compiled = height * width <= self.ready_rays  # else it may compile: not a rate to keep
    with self._render_lock:
      start = time.perf_counter()
      out = self.scene.render(draw, camera.viewer_to_c2w(wxyz, position, self.scale), height,
                              width, fov, cancelled)
    if out is None:
      return False
    rendered = time.perf_counter()
    image, caption = output_image(out, self.gui_output.value, self.scene.near, self.scene.far)
    view.client.scene.set_background_image(image, format="jpeg", jpeg_quality=90)
    done = time.perf_counter()
    if compiled:
      self.meter.add(height * width, rendered - start, done - start)
    self.frames_sent += 1
    self.frame_log.append((done, width, height, moving, done - start))
    self.last_frame = image
    self.last_info = (f"{width}×{height} {'moving' if moving else 'still'}, "
                      f"{1000 * (done - start):.0f} ms")
    self.gui_frame.value, self.gui_range.value = self.last_info, caption
    return True
