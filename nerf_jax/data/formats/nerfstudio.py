"""The nerfstudio / instant-ngp `transforms.json` format (data/nerfstudio.py): what
nerf-process writes."""

import json
import os

from nerf_jax.data import formats, nerfstudio


def detect(path):
  """Whether `path` is a transforms.json file or a folder holding one."""
  return path.endswith(nerfstudio.FILENAME) or os.path.isfile(os.path.join(path,
                                                                           nerfstudio.FILENAME))


def load(path, background, settings):
  """(train, test) of `nerfstudio.load_split`: settings.factor downscales, min_sharpness drops
  blurry frames, holdout_from -1 holds out every 8th frame unless the file names its test
  images."""
  return nerfstudio.load_split(path, background, settings.factor or 1, settings.holdout_from,
                               settings.min_sharpness)


def photo_paths(path):
  """The files of transforms.json's frames that exist (full size: data.factor downscales
  them); None where `path` names no transforms.json file."""
  meta = path if path.endswith(nerfstudio.FILENAME) else os.path.join(path, nerfstudio.FILENAME)
  if not os.path.isfile(meta):
    return None
  with open(meta) as f:
    frames = json.load(f).get("frames", [])
  root = os.path.dirname(meta)
  files = [os.path.join(root, frame.get("file_path", "")) for frame in frames]
  return [p for p in files if os.path.isfile(p)]


FORMAT = formats.Format("nerfstudio", detect, load, photo_paths=photo_paths,
                        expected=nerfstudio.FILENAME)
