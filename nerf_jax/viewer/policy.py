"""How large a frame to render, and rendering it so that a camera move can stop it.

While the camera moves the viewer renders the largest of a few fixed frame heights
(`MOVING_HEIGHTS`) that the measured render rate draws within 1 / target_fps seconds (as
nerfstudio's viewer does) among those whose frames compile nothing (`ready_heights`); when it
stops, one still frame at full resolution, in chunks, checking between chunks whether the
camera has moved again. Rays are made and rendered in chunks of one fixed size, so the
compiled shapes do not depend on the frame size, only on how many rays a chunk holds (the
marcher's query buffers, see image_renderer.Draw.compile_steps).
"""

import jax
import numpy as np

# Frame heights in pixels while the camera moves; the width follows the canvas's aspect.
MOVING_HEIGHTS = (16, 24, 32, 48, 64, 80, 96, 128, 160, 192, 256)


def _num_rays(height, aspect):
  """Pixels of a frame `height` pixels tall at width / height `aspect` (camera.frame_size)."""
  return height * max(1, round(height * aspect))


def ready_heights(ready_rays, aspect, heights=MOVING_HEIGHTS):
  """The set of `heights` whose frames at `aspect` hold at most `ready_rays` rays (float: the
  most rays a frame may hold and compile nothing; math.inf once everything is compiled)."""
  return {h for h in heights if _num_rays(h, aspect) <= ready_rays}


def moving_height(rays_per_second, aspect, target_fps, overhead_s=0.0, max_height=None,
                  heights=MOVING_HEIGHTS, ready=None):
  """The largest of `heights` in `ready` (at most `max_height`) whose frame renders at
  `target_fps`.

  rays_per_second: float, the measured render rate. aspect: float, width / height.
  overhead_s: float, seconds per frame besides rendering (encoding, sending).
  ready: set of heights that render without compiling (None: all of them).
  Returns an int height: the smallest candidate when even that misses the target, the
  smallest of `heights` when no height is ready (it compiles the least).
  """
  budget = 1.0 / target_fps - overhead_s
  candidates = [h for h in heights if (ready is None or h in ready)
                and (max_height is None or h <= max_height)]
  best = candidates[0] if candidates else heights[0]
  for h in candidates:
    if _num_rays(h, aspect) <= budget * rays_per_second:
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
