"""Images resampled on the host (numpy), for the data layer: bilinear sampling at continuous
pixel indices (a lens's distortion removed, data/lens.py; photos seen through one pinhole,
data/one_camera.py) and the block average that downscales photos by an integer factor
(data.factor's LLFF, COLMAP and transforms.json folders, Blender's half_res, the multiscale
converter).

Indices are continuous: pixel k's value sits at index k (a pixel-centre convention of the
caller's is its own offset).
"""

import numpy as np


def bilinear(image, rows, columns):
  """`image` float [h, w, ...] at the points (rows, columns) (float [...], broadcast together;
  clamped to the image, so beyond its border the nearest edge pixel): float [..., ...] in
  `image`'s dtype, the weights rounded to it (float32 images: float32 arithmetic)."""
  height, width = image.shape[:2]
  rows = np.clip(rows, 0, height - 1)
  columns = np.clip(columns, 0, width - 1)
  r0 = np.clip(np.floor(rows), 0, max(height - 2, 0)).astype(np.int64)  # r0 + 1 stays inside
  c0 = np.clip(np.floor(columns), 0, max(width - 2, 0)).astype(np.int64)
  r1, c1 = np.minimum(r0 + 1, height - 1), np.minimum(c0 + 1, width - 1)
  trailing = (...,) + (None,) * (image.ndim - 2)  # a weight per point, across the channels
  wr = (rows - r0).astype(image.dtype)[trailing]
  wc = (columns - c0).astype(image.dtype)[trailing]
  top = image[r0, c0] * (1 - wc) + image[r0, c1] * wc
  bottom = image[r1, c0] * (1 - wc) + image[r1, c1] * wc
  return top * (1 - wr) + bottom * wr


def block_mean(images, factor):
  """float [..., H, W, C] -> [..., H // factor, W // factor, C]: the mean of each factor x
  factor block of pixels (int factor >= 1; a partial last row or column of blocks is dropped),
  in `images`' dtype; `images` itself with factor 1."""
  if factor == 1:
    return images
  height, width = images.shape[-3] // factor, images.shape[-2] // factor
  blocks = images[..., :height * factor, :width * factor, :]
  return blocks.reshape(images.shape[:-3] + (height, factor, width, factor, images.shape[-1])
                        ).mean((-4, -2))
