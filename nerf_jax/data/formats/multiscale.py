"""mip-NeRF's multiscale format (`metadata.json`, data/multicam.py): per-image cameras, its
own train and test splits."""

import os

from nerf_jax.data import formats, multicam, validate


def detect(path):
  """Whether the folder `path` holds metadata.json."""
  return os.path.isfile(os.path.join(path, multicam.FILENAME))


def load(path, background, settings):
  """(train, test): the folder's own splits (`multicam.load`; settings.holdout_from does not
  apply)."""
  del settings
  return tuple(multicam.load(path, background, s) for s in ("train", "test"))


def background(path):
  """'white' for a folder of RGBA images (made from Blender's; the first training image
  decides), the convention its tables score it on; None (black) for RGB images."""
  if _first_image_channels(path) == 4:
    return "white", "the convention of mip-NeRF's multiscale data (Blender's RGBA, on white)"
  return None


def _first_image_channels(path):
  """The channels of the first training image a multiscale folder's metadata.json names, or
  None where it names none that exists (multicam.load then says what is wrong)."""
  meta = validate.read_json(os.path.join(path, multicam.FILENAME))
  train = meta.get("train") if isinstance(meta, dict) else None
  files = train.get("file_path") if isinstance(train, dict) else None
  if not isinstance(files, list) or not files or not isinstance(files[0], str):
    return None
  image_path = os.path.join(path, files[0])
  return validate.read_image(image_path).shape[-1] if os.path.isfile(image_path) else None


# `expected` '': the one line for data of no known format has never named metadata.json.
FORMAT = formats.Format("multiscale", detect, load, background)
