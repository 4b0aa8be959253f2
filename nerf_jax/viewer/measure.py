"""Measure the viewer's goals in a headless browser (docs/viewer.md has the figures).

  PYTHONPATH=. python -m nerf_jax.viewer.measure --workdir=/tmp/viewer_run [--screenshot=F]

Prints one JSON record: seconds from the model restored (the command's "restored" line) to
the address printed, to the first frame in the page and to every frame size compiled (and from
the command to the first frame); frames per second and frame sizes while dragging, the still
frame's render time and its delay after the drag ends (both once the viewer is warm). Needs viser, playwright and /usr/bin/chromium.
With --training: train rays/s with config.viewer.enabled off and on, nobody watching.
"""

import json
import math
import subprocess
import sys
import threading
import time

from absl import app, flags

CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist"]


def _frame_text(page):
  """The page's 'Frame' field (e.g. '178×100 still, 230 ms'), or ''."""
  values = page.locator("input").evaluate_all("els => els.map(e => e.value)")
  return next((v for v in values if " ms" in v), "")


def _timed_lines(stream):
  """A list that a daemon thread fills with (time.perf_counter(), line) of `stream` as read."""
  lines = []
  threading.Thread(target=lambda: lines.extend((time.perf_counter(), l) for l in stream),
                   daemon=True).start()
  return lines


def _line_time(lines, prefix, timeout=600.0):
  """When the first line starting with `prefix` was read (waiting up to `timeout` s for it)."""
  end = time.perf_counter() + timeout
  while time.perf_counter() < end:
    found = next((t for t, line in list(lines) if line.startswith(prefix)), None)
    if found is not None:
      return found
    time.sleep(0.01)
  raise TimeoutError(f"no line starting with {prefix!r} in {timeout} s")


def command_to_first_frame(browser, workdir, port):
  """Seconds from the command to the model restored, and from that to the address printed, to
  the first frame's stats in the page (page load in the browser included) and to the viewer's
  line saying every frame size is compiled: a dict."""
  start = time.perf_counter()
  proc = subprocess.Popen([sys.executable, "-m", "nerf_jax.viewer", f"--workdir={workdir}",
                           f"--port={port}"], stdout=subprocess.PIPE, text=True)
  try:
    lines = _timed_lines(proc.stdout)
    restored, opened = _line_time(lines, "restored"), _line_time(lines, "viewer: open")
    page = browser.new_page(viewport={"width": 1000, "height": 600})
    page.goto(f"http://localhost:{port}")
    while not _frame_text(page):
      page.wait_for_timeout(20)
    first = time.perf_counter()
    page.close()
    warm = _line_time(lines, "viewer: every frame size compiled")
  finally:
    proc.terminate()
    proc.wait()
  return {"command_to_restored_s": round(restored - start, 2),
          "restored_to_address_s": round(opened - restored, 2),
          "restored_to_first_frame_s": round(first - restored, 2),
          "restored_to_all_sizes_compiled_s": round(warm - restored, 2),
          "command_to_first_frame_s": round(first - start, 2)}


def dragging(browser, workdir, port, seconds=4.0, screenshot=""):
  """Frames per second and sizes while dragging for `seconds`, then the still frame."""
  from nerf_jax.viewer import scene, server  # pylint: disable=import-outside-toplevel
  loaded, params, step = scene.from_workdir(workdir)
  viewer = server.Viewer(loaded, params, port=port, step=step)
  try:
    viewer.warmed.wait()  # the steady state: every frame size compiled
    page = browser.new_page(viewport={"width": 1000, "height": 600})
    page.goto(viewer.url)
    while not any(not log[3] for log in viewer.frame_log):
      page.wait_for_timeout(50)
    page.wait_for_timeout(1000)
    page.mouse.move(300, 400)
    page.mouse.down()
    view = next(iter(viewer._views.values()))  # pylint: disable=protected-access
    start, sent, i, moves = time.perf_counter(), len(viewer.frame_log), 0, view.version
    while time.perf_counter() - start < seconds:
      i += 1
      page.mouse.move(300 + 200 * math.sin(i / 10), 400 - i % 50)
      page.wait_for_timeout(15)
    page.mouse.up()
    released = time.perf_counter()
    moves = view.version - moves
    during = [log for log in viewer.frame_log[sent:] if log[0] <= released]
    moving = [log for log in during if log[3]]
    while not any(not log[3] for log in viewer.frame_log[sent + len(during):]):
      page.wait_for_timeout(10)
    still = next(log for log in viewer.frame_log[sent + len(during):] if not log[3])
    if screenshot:
      page.wait_for_timeout(1000)
      page.mouse.click(288, 81)  # close viser's 'software WebGL' notice
      page.wait_for_timeout(500)
      page.screenshot(path=screenshot)
    page.close()
  finally:
    viewer.close()
  return {"drag_seconds": round(released - start, 2),
          "camera_updates_per_second": round(moves / (released - start), 1),
          "moving_frames_per_second": round(len(moving) / (released - start), 1),
          "moving_frame_sizes": sorted({f"{w}x{h}" for _, w, h, _, _ in moving}),
          "moving_frame_ms_median": round(1000 * sorted(s for *_, s in moving)[len(moving) // 2])
                                    if moving else None,
          "still_size": f"{still[1]}x{still[2]}", "still_render_ms": round(1000 * still[4]),
          "still_after_release_s": round(still[0] - released, 3),
          "rays_per_second_estimate": round(viewer.meter.rays_per_second)}


class _FakeClient:
  """A browser stand-in for `synthetic_drag`: a camera and a sink for frames."""

  def __init__(self, wxyz, position, fov, width=1000, height=600):
    cam = type("Camera", (), {})()
    cam.wxyz, cam.position, cam.fov = wxyz, position, fov
    cam.image_width, cam.image_height = width, height
    sink = type("Scene", (), {"set_background_image": lambda *a, **k: None})()
    self.camera, self.scene, self.client_id = cam, sink, -1


def synthetic_drag(workdir, port, seconds=4.0, hz=30.0):
  """The server side alone: camera updates at `hz` orbiting the scene, no browser (whose
  software WebGL shares the 2 cores and sends few updates); frames per second sent."""
  from nerf_jax.viewer import camera, scene, server  # pylint: disable=import-outside-toplevel
  loaded, params, step = scene.from_workdir(workdir)
  viewer = server.Viewer(loaded, params, port=port, step=step)
  try:
    viewer.warmed.wait()  # the steady state: every frame size compiled
    wxyz, position = camera.c2w_to_viewer(loaded.poses[0])
    client = _FakeClient(wxyz, position, loaded.fov())
    view = server._View(client)  # pylint: disable=protected-access
    viewer._views[-1] = view  # pylint: disable=protected-access
    start, sent = time.perf_counter(), len(viewer.frame_log)
    turn = camera.quaternion_to_matrix([math.cos(0.01), 0, 0, math.sin(0.01)])  # about z
    while time.perf_counter() - start < seconds:
      c2w = camera.viewer_to_c2w(client.camera.wxyz, client.camera.position)
      c2w[:3, :] = turn @ c2w[:3, :]
      client.camera.wxyz, client.camera.position = camera.c2w_to_viewer(c2w)
      viewer._moved(view)  # pylint: disable=protected-access
      time.sleep(1.0 / hz)
    released = time.perf_counter()
    moving = [log for log in viewer.frame_log[sent:] if log[3] and log[0] <= released]
    while not any(not log[3] for log in viewer.frame_log[sent + len(moving):]):
      time.sleep(0.01)
    still = next(log for log in viewer.frame_log[sent + len(moving):] if not log[3])
  finally:
    viewer.close()
  return {"synthetic_moving_frames_per_second": round(len(moving) / (released - start), 1),
          "synthetic_moving_frame_sizes": sorted({f"{w}x{h}" for _, w, h, _, _ in moving}),
          "synthetic_still_after_release_s": round(still[0] - released, 3),
          "synthetic_still_render_ms": round(1000 * still[4])}


def training_overhead(pairs=2, steps=60):
  """Train rays/s with the viewer off and on (nobody watching), alternating `pairs` times.

  The fast config on 64×64 images; the first log record (compilation) is left out.
  """
  import tempfile  # pylint: disable=import-outside-toplevel
  from nerf_jax.configs import fast  # pylint: disable=import-outside-toplevel
  from nerf_jax.run import train_lib  # pylint: disable=import-outside-toplevel
  from nerf_jax.viewer import training  # pylint: disable=import-outside-toplevel
  rates = {False: [], True: []}
  for _ in range(pairs):
    for enabled in (False, True):
      config = fast.get_config()
      config.data.image_size, config.train.max_steps, config.train.log_every = 64, steps, 20
      config.train.checkpoint_every, config.render.after_training = steps, False
      config.train.tensorboard, config.train.eval_views = False, 0
      config.viewer.enabled, config.viewer.port = enabled, 7060
      with tempfile.TemporaryDirectory() as workdir:
        train_lib.train_and_evaluate(config, workdir, watchers=(training.start,))
        with open(f"{workdir}/metrics.jsonl") as f:
          records = [json.loads(l) for l in f if "rays_per_second" in l]
      rates[enabled] += [r["rays_per_second"] for r in records[1:]]
  off, on = (sum(rates[k]) / len(rates[k]) for k in (False, True))
  return {"train_rays_per_second_viewer_off": round(off), "train_rays_per_second_viewer_on":
          round(on), "train_slowdown_nobody_watching": round(1 - on / off, 3)}


def main(_):
  if flags.FLAGS.training:
    print(json.dumps(training_overhead()))
    return
  from playwright.sync_api import sync_playwright  # pylint: disable=import-outside-toplevel
  workdir, port = flags.FLAGS.workdir, flags.FLAGS.port
  with sync_playwright() as p:
    browser = p.chromium.launch(executable_path=flags.FLAGS.chromium, args=CHROMIUM_ARGS)
    record = command_to_first_frame(browser, workdir, port)
    record.update(dragging(browser, workdir, port + 1, screenshot=flags.FLAGS.screenshot))
    browser.close()
  record.update(synthetic_drag(workdir, port + 2))
  print(json.dumps(record))


if __name__ == "__main__":
  flags.DEFINE_string("workdir", None, "Training run directory.", required=True)
  flags.DEFINE_integer("port", 7050, "First of two ports to use.")
  flags.DEFINE_string("chromium", "/usr/bin/chromium", "The browser.")
  flags.DEFINE_string("screenshot", "", "Save a screenshot of the page after the drag here.")
  flags.DEFINE_bool("training", False, "Measure the training slowdown instead (no browser).")
  app.run(main)
