"""Images for people: float images to uint8, and depth maps colour-mapped."""

import numpy as np

# Control points of a perceptually ordered colour map (dark blue -> teal -> yellow), for depth.
_CMAP = np.array([[0.05, 0.03, 0.25], [0.23, 0.30, 0.55], [0.13, 0.57, 0.55],
                  [0.37, 0.79, 0.38], [0.99, 0.91, 0.14]])


def colorize(depth, near, far):
  """Colour-mapped depth: uint8 [..., 3] from depth float32 [...] (near = dark, far = bright)."""
  x = np.clip((np.asarray(depth) - near) / max(far - near, 1e-9), 0.0, 1.0)
  pos = np.linspace(0.0, 1.0, len(_CMAP))
  rgb = np.stack([np.interp(x, pos, _CMAP[:, c]) for c in range(3)], axis=-1)
  return to_uint8(rgb)


def to_uint8(image):
  """uint8 image from a float image in [0, 1]."""
  return (np.clip(np.asarray(image), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
