"""Checked conversions of raw file contents into `Dataset` arrays.

Every function raises `DataError` with a one-line message that starts with `where` (the file and
field at fault) when its input is malformed.
"""

import json
import os

import imageio.v3 as iio
import numpy as np

from nerf_jax.render import background as background_lib
from nerf_jax.data.dataset import DataError


def parse_background(background):
  """'black', 'white', 'random' or an RGB triple in [0, 1] -> float64 [3] (background.parse)."""
  try:
    return background_lib.parse(background, "background").astype(np.float64)
  except ValueError as e:
    raise DataError(str(e)) from None


def composite(rgba, background):
  """rgba: float [..., 3 or 4] straight (unpremultiplied) colour -> float32 [..., 3]."""
  if rgba.shape[-1] == 3:
    return rgba.astype(np.float32)
  alpha = rgba[..., 3:]
  return (rgba[..., :3] * alpha + background * (1.0 - alpha)).astype(np.float32)


def unit_images(images, where):
  """uint8/uint16 or float images -> float64 in [0, 1]; DataError if non-finite/out of range."""
  images = np.asarray(images)
  if images.shape[-1:] not in ((3,), (4,)):
    raise DataError(f"{where}: shape {images.shape} has {images.shape[-1:]} channels; expected "
                    "3 (RGB) or 4 (RGBA)")
  if np.issubdtype(images.dtype, np.integer):
    return images / float(np.iinfo(images.dtype).max)
  if not np.all(np.isfinite(images)):
    raise DataError(f"{where}: contains NaN or inf")
  if images.min() < 0.0 or images.max() > 1.0:
    raise DataError(f"{where}: values in [{images.min():g}, {images.max():g}]; expected [0, 1]")
  return images.astype(np.float64)


def floats(value, where):
  """Anything array-like -> float64 array."""
  try:
    return np.asarray(value, np.float64)
  except (TypeError, ValueError):
    raise DataError(f"{where}: not numeric ({str(value)[:40]})") from None


def poses(value, where):
  """[N, 3, 4] or [N, 4, 4] camera-to-world -> float32 [N, 4, 4]."""
  poses = floats(value, where)
  if poses.ndim != 3 or poses.shape[1:] not in ((3, 4), (4, 4)):
    raise DataError(f"{where}: shape {poses.shape}; expected [N, 4, 4] or [N, 3, 4]")
  if not np.all(np.isfinite(poses)):
    raise DataError(f"{where}: contains NaN or inf")
  bottom = np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(poses), 1, 4))
  return np.concatenate([poses[:, :3], bottom], 1).astype(np.float32)


def scalar(value, where):
  """One finite number -> float."""
  value = floats(value, where)
  if value.size != 1 or not np.isfinite(value).all():
    raise DataError(f"{where}: expected one finite number, got shape {value.shape}")
  return float(value.reshape(()))


def read_image(path):
  """An image file -> float64 [H, W, 3 or 4] in [0, 1]."""
  try:
    image = iio.imread(path)
  except Exception as e:  # imageio raises many types for unreadable files
    lines = str(e).strip().splitlines() or [type(e).__name__]  # imageio's can be many lines
    raise DataError(f"{path}: cannot read image ({lines[0]})") from None
  return unit_images(image, path)


def read_grey(path):
  """A grey image file (a mask) -> float64 [H, W] in [0, 1]; an RGB(A) file gives its first
  channel."""
  try:
    image = np.asarray(iio.imread(path))
  except Exception as e:  # imageio raises many types for unreadable files
    lines = str(e).strip().splitlines() or [type(e).__name__]
    raise DataError(f"{path}: cannot read image ({lines[0]})") from None
  image = image if image.ndim == 2 else image[..., 0]
  if np.issubdtype(image.dtype, np.bool_):
    return image.astype(np.float64)
  if np.issubdtype(image.dtype, np.integer):
    return image / float(np.iinfo(image.dtype).max)
  if not np.all(np.isfinite(image)):
    raise DataError(f"{path}: contains NaN or inf")
  return image.astype(np.float64)


def read_json(path):
  """The JSON document in the file `path`; DataError naming the file for a missing file or a
  malformed document (its line and column)."""
  if not os.path.isfile(path):
    raise DataError(f"{path}: no such file")
  with open(path) as f:
    try:
      return json.load(f)
    except json.JSONDecodeError as e:
      raise DataError(f"{path}: malformed JSON at line {e.lineno} column {e.colno}: "
                      f"{e.msg}") from None
