"""How large a frame to render, and rendering it so that a camera move can stop it.

While the camera moves the viewer renders the largest of a few fixed frame heights
(`MOVING_HEIGHTS`) that the measured render rate draws within 1 / target_fps seconds (as
nerfstudio's viewer does); when it stops, one still frame at full resolution, in chunks, checking
between chunks whether the camera has moved again. The renderer pads every call to a fixed
chunk of rays, so no frame size compiles anything new.
"""

import jax
import numpy as np

# Frame heights in pixels while the camera moves; the width follows the canvas's aspect.
MOVING_HEIGHTS = (16, 24, 32, 48, 64, 80, 96, 128, 160, 192, 256)


def moving_height(rays_per_second, aspect, target_fps, overhead_s=0.0, max_height=None,
                  heights=MOVING_HEIGHTS):
  """The largest of `heights` (at most `max_height`) whose frame renders at `target_fps`.

  rays_per_second: float, the measured render rate. aspect: float, width / height.
  overhead_s: float, seconds per frame besides rendering (encoding, sending).
  Returns an int height; the smallest height when even that misses the target.
  """
  budget = 1.0 / target_fps - overhead_s
  best = heights[0]
  for h in heights:
    if max_height is not None and h > max_height:
      break
    if h * max(1, round(h * aspect)) <= budget * rays_per_second:
      best = h
  return best


class RateMeter:
  """Running estimates of the render rate (rays/s) and the per-frame overhead (s).

  Exponential moving averages, so a rate measured under load recovers when the load goes.
  """

  def __init__(self, rays_per_second=1e5, overhead_s=0.01, smoothing=0.3):
    self.rays_per_second, self.overhead_s, self.smoothing = rays_per_second, overhead_s, smoothing

  def add(self, num_rays, render_s, total_s):
    """Record a frame of `num_rays` rays rendered in `render_s` and shown in `total_s` seconds."""
    a = self.smoothing
    rate = num_rays / max(render_s, 1e-6)  # a timer tick of 0 s must not divide by zero
    self.rays_per_second = (1 - a) * self.rays_per_second + a * rate
    self.overhead_s = (1 - a) * self.overhead_s + a * max(total_s - render_s, 0.0)


def render_in_chunks(draw, rays, chunk, background, cancelled=None):
  """Render rays with `draw` one chunk at a time; stop early when `cancelled()` is true.

  draw: fn(rays, background) -> numpy dict of arrays [n, ...] (image_renderer's draw).
  rays: rays.Rays [H, W]. chunk: int, rays per call (config.render.chunk: the size the renderer
  compiled for). cancelled: fn() -> bool checked before every chunk, or None.
  Returns numpy dict rgb [H, W, 3], depth [H, W], acc [H, W], or None when cancelled.
  """
  shape = rays.shape
  flat = jax.tree_util.tree_map(np.asarray, rays.reshape(-1))
  pieces = []
  for i in range(0, int(np.prod(shape)), chunk):
    if cancelled is not None and cancelled():
      return None
    pieces.append(draw(jax.tree_util.tree_map(lambda a: a[i:i + chunk], flat), background))
  return {k: np.concatenate([p[k] for p in pieces]).reshape(*shape, *pieces[0][k].shape[1:])
          for k in pieces[0]}
