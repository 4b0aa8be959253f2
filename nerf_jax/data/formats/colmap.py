"""A folder with a COLMAP model (cameras, images, points3D in sparse/0, sparse or
colmap/sparse/0) and its images (data/colmap.py)."""

import os

from nerf_jax.data import colmap, formats


def detect(path):
  """Whether the folder `path` holds a COLMAP model (`colmap.model_dir`)."""
  return os.path.isdir(path) and bool(colmap.model_dir(path))


def load(path, background, settings):
  """(train, test) of `colmap.load_split` (settings.factor downscales; holdout_from -1 holds
  out every 8th image)."""
  return colmap.load_split(path, background, settings.factor or 1, settings.holdout_from)


FORMAT = formats.Format("colmap", detect, load,
                        expected=f"a COLMAP model in {' or '.join(colmap.MODEL_DIRS)}")
