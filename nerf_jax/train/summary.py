"""TensorBoard event files (tensorboardX) in `workdir/tb/`: scalars at log steps, images at evals.

  tensorboard --logdir runs/

Scalars: train/loss, train/psnr, train/learning_rate, train/rays_per_second, eval/psnr.
Images: eval/rgb, eval/depth (colour-mapped, near = dark), eval/truth of the first test view.
The JSON-lines log (metrics.jsonl) is written independently of this.
"""

import os

import numpy as np


class Writer:
  """A TensorBoard writer; with enabled=False (or without tensorboardX) every call does nothing."""

  def __init__(self, workdir, enabled=True):
    self._writer = None
    if not enabled:
      return
    try:
      from tensorboardX import SummaryWriter  # imported lazily: protobuf is slow to import
    except ImportError:
      print("tensorboardX is not installed: no TensorBoard events (pip install tensorboardX)")
      return
    self._writer = SummaryWriter(os.path.join(workdir, "tb"))

  def scalars(self, step, values):
    """values: {tag: float} at `step`."""
    if self._writer is None:
      return
    for tag, value in values.items():
      self._writer.add_scalar(tag, float(value), int(step))
    self._writer.flush()

  def images(self, step, images):
    """images: {tag: uint8 or float in [0, 1] [H, W, 3]} at `step`."""
    if self._writer is None:
      return
    for tag, image in images.items():
      image = np.asarray(image)
      if image.dtype != np.uint8:
        image = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
      self._writer.add_image(tag, image, int(step), dataformats="HWC")
    self._writer.flush()

  def close(self):
    if self._writer is not None:
      self._writer.close()
      self._writer = None
