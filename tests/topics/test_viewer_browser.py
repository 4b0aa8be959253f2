"""End to end: the viewer's page in a real headless browser (Debian's chromium via playwright).

A tiny model is trained for a few dozen steps; the viewer serves it; the page must show the
frame the server rendered, and dragging the camera must bring new, different frames (reduced
resolution while moving, then a full-resolution still).
"""

import importlib.util
import os
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from nerf_jax.run import train_lib
from tests.helpers import TINY_GRID, small_config

CHROMIUM = os.environ.get("NERF_JAX_CHROMIUM", "/usr/bin/chromium")
INSTALL = ('apt-get update && apt-get install -y chromium && pip install -e ".[viewer-test]"')
from tests.helpers import ROOT


def _missing():
  """Why the browser test cannot run here, or None."""
  absent = [m for m in ("viser", "playwright") if importlib.util.find_spec(m) is None]
  if not (os.path.exists(CHROMIUM) or shutil.which(CHROMIUM)):
    absent.append(CHROMIUM)
  return f"needs {', '.join(absent)}; install with: {INSTALL}" if absent else None


pytestmark = [pytest.mark.skipif(_missing() is not None, reason=str(_missing())),
              pytest.mark.slow]  # a browser, a process, waits on the wall clock


# The tiny grid run on images of 32² (still frames have the training resolution: enough pixels
# for the page's copy to correlate with), empty space white (a high-contrast frame after few
# steps).
TINY = {**TINY_GRID, "data.image_size": 32, "data.background": "white",
        "train.tensorboard": False}


def _free_port():
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    return s.getsockname()[1]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
  path = str(tmp_path_factory.mktemp("viewer_run"))
  train_lib.train_and_evaluate(small_config(TINY, base="fast"), path)
  return path


def _wait(page, condition, seconds, what):
  """Poll `condition` while the page runs (playwright's sync calls drive its events)."""
  end = time.time() + seconds
  while not condition():
    if time.time() > end:
      raise AssertionError(f"timed out after {seconds} s waiting for {what}")
    page.wait_for_timeout(50)


def _shown(shot, frame):
  """Correlation (luminance) of the page's pixels, averaged over each frame pixel's area, with
  the frame sent, away from the GUI panel and the notification: near 1 when the page shows
  that frame (drawn lines and the browser's smoothing take a little off)."""
  big_h, big_w = shot.shape[:2]
  h, w = frame.shape[:2]
  cell = (np.arange(big_h)[:, None] * h // big_h) * w + np.arange(big_w)[None, :] * w // big_w
  lum = np.asarray(shot[..., :3], np.float64).mean(-1)
  area = np.bincount(cell.ravel(), lum.ravel(), h * w) / np.bincount(cell.ravel(), None, h * w)
  region = np.zeros((h, w), bool)
  region[h // 3:, :w // 2] = True
  sent = np.asarray(frame, np.float64).mean(-1)
  return float(np.corrcoef(area.reshape(h, w)[region], sent[region])[0, 1])


def _shot_showing(page, viewer, seconds, unlike=None):
  """Screenshots, polled until the page shows the viewer's newest frame (correlation > 0.8)
  and, given `unlike` (an earlier screenshot), differs from it: how soon a received frame
  reaches the canvas depends on the machine's load, so a fixed pause is flaky. Returns the
  screenshot, the frame, and their correlation (the best seen on a timeout, for the message)."""
  import imageio.v2 as imageio  # pylint: disable=import-outside-toplevel
  end, best = time.time() + seconds, None
  while True:
    frame = viewer.last_frame
    shot = imageio.imread(page.screenshot())
    seen = (shot, frame, _shown(shot, frame))
    best = seen if best is None or seen[2] > best[2] else best
    changed = unlike is None or np.abs(shot.astype(int) - unlike.astype(int)).mean() > 2.0
    if (seen[2] > 0.8 and changed) or time.time() > end:
      return seen if seen[2] > 0.8 and changed else best
    page.wait_for_timeout(250)


def test_page_shows_rendered_frames_and_dragging_changes_them(workdir):
  from playwright.sync_api import sync_playwright  # pylint: disable=import-outside-toplevel
  from nerf_jax.viewer import scene, server  # pylint: disable=import-outside-toplevel

  loaded, params, step = scene.from_workdir(workdir)
  viewer = server.Viewer(loaded, params, port=_free_port(), step=step, out_dir=workdir)
  try:
    with sync_playwright() as p:
      browser = p.chromium.launch(executable_path=CHROMIUM, args=[
          "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"])
      page = browser.new_page(viewport={"width": 1000, "height": 600})
      page.goto(viewer.url)
      _wait(page, lambda: any(not log[3] for log in viewer.frame_log), 60, "a still frame")
      before, first, corr = _shot_showing(page, viewer, 30)
      assert first.shape[0] == loaded.height  # still frames have the training resolution
      assert corr > 0.8, f"the page does not show the frame sent (correlation {corr:.2f})"

      sent = len(viewer.frame_log)
      page.mouse.move(200, 300)
      page.mouse.down()
      for i in range(15):
        page.mouse.move(200 + 12 * i, 300 + 2 * i)
        page.wait_for_timeout(40)
      page.mouse.up()
      log = viewer.frame_log
      _wait(page, lambda: len(log) > sent + 1 and not log[-1][3], 60, "a still frame after "
            "dragging")  # the newest frame: the camera has stopped
      after, last, corr_after = _shot_showing(page, viewer, 30, unlike=before)
      browser.close()
    moves = [log for log in viewer.frame_log[sent:] if log[3]]
    assert moves, "no reduced-resolution frame while dragging"
    assert np.abs(last.astype(int) - first.astype(int)).mean() > 2.0
    assert corr_after > 0.8, f"the page does not show the new frame (correlation {corr_after:.2f})"
    assert np.abs(after.astype(int) - before.astype(int)).mean() > 2.0
  finally:
    viewer.close()


@pytest.mark.slow  # a subprocess
def test_command_without_checkpoint_prints_one_line(tmp_path):
  result = subprocess.run([sys.executable, "-m", "nerf_jax.viewer", f"--workdir={tmp_path}"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": ROOT})
  assert result.returncode == 1
  lines = result.stderr.strip().splitlines()
  assert len(lines) == 1 and lines[0].startswith("error:") and "config.json" in lines[0]
