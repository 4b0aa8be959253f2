"""The LLFF format of forward-facing captures (`poses_bounds.npy` and `images/`,
data/llff.py); mip-NeRF 360's scenes come in it too."""

import os

from nerf_jax.data import formats
from nerf_jax.data.llff import load_llff

TABLE = "poses_bounds.npy"  # what marks an LLFF folder
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")  # the photos load_llff reads


def detect(path):
  """Whether the folder `path` holds poses_bounds.npy."""
  return os.path.isfile(os.path.join(path, TABLE))


def load(path, background, settings):
  """(train, test) of `load_llff` (settings.factor, bd_factor: 0 keeps the file's units,
  recenter), holding out every 8th view (the original NeRF's convention) at holdout_from -1.
  `background` is unused: LLFF's photographs are opaque."""
  del background
  dataset = load_llff(path, factor=settings.factor or 1, bd_factor=settings.bd_factor or None,
                      recenter=settings.recenter)
  holdout_from = settings.holdout_from
  return dataset.split_every(8) if holdout_from == -1 else dataset.split(holdout_from)


def photo_paths(path):
  """The full-size photos of `images/` (what data.factor downscales); [] without the folder."""
  folder = os.path.join(path, "images")
  if not os.path.isdir(folder):
    return []
  return [os.path.join(folder, n) for n in sorted(os.listdir(folder))
          if n.lower().endswith(_IMAGE_SUFFIXES)]


FORMAT = formats.Format("llff", detect, load, photo_paths=photo_paths, expected=TABLE)
