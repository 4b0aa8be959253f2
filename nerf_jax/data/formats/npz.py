"""The tiny_nerf format: one .npz file of images, poses and a focal length."""

import os
import zipfile

import numpy as np

from nerf_jax.data import formats, validate
from nerf_jax.data.dataset import DataError, Dataset
from nerf_jax.data.validate import composite, parse_background


def load_npz(path, background=(0.0, 0.0, 0.0)):
  """The tiny_nerf format: `images` [N, H, W, 3|4], `poses` [N, 4|3, 4], `focal`; optional
  `near`, `far` (default 2, 6), `pixel_center` (default 0: pixel corners, as the Keras reference
  reads tiny_nerf_data.npz), `masks` [N, H, W] (1 keep, 0 ignore: Dataset.masks),
  ground-truth `depths`, `accs` and the RGB `background` of RGB
  images (default unknown: (0, 0, 0)). RGBA is composited on `background` (see
  `parse_background`) and its alpha becomes `accs`. Returns a Dataset."""
  if not os.path.isfile(path):
    raise DataError(f"{path}: no such file")
  try:
    with np.load(path) as archive:
      data = dict(archive)
  except (OSError, ValueError, TypeError, zipfile.BadZipFile) as e:
    raise DataError(f"{path}: not a readable .npz archive ({type(e).__name__})") from None
  for key in ("images", "poses", "focal"):
    if key not in data:
      raise DataError(f"{path}: missing array {key!r} (has: {', '.join(sorted(data))})")
  images = validate.unit_images(data["images"], f"{path}: 'images'")
  if images.ndim != 4:
    raise DataError(f"{path}: 'images' has shape {images.shape}; expected [N, H, W, 3 or 4]")
  poses = validate.poses(data["poses"], f"{path}: 'poses'")
  if len(poses) != len(images):
    raise DataError(f"{path}: 'images' has {len(images)} views but 'poses' has {len(poses)}")
  focal = validate.scalar(data["focal"], f"{path}: 'focal'")
  num, height, width = images.shape[:3]
  extra = {k: data[k].astype(np.float32) for k in ("depths", "accs", "masks")
           if k in data and data[k].shape == (num, height, width)}
  if "masks" in data and "masks" not in extra:
    raise DataError(f"{path}: 'masks' has shape {data['masks'].shape}; expected "
                    f"{(num, height, width)}")
  if images.shape[-1] == 4:
    bg = parse_background(background)
    extra["accs"] = images[..., 3].astype(np.float32)
  else:
    bg = parse_background(data["background"] if "background" in data else (0.0, 0.0, 0.0))
  return Dataset(composite(images, bg), poses, (focal, focal, width * 0.5, height * 0.5),
                 near=validate.scalar(data.get("near", 2.0), f"{path}: 'near'"),
                 far=validate.scalar(data.get("far", 6.0), f"{path}: 'far'"), name=path,
                 background=tuple(bg.tolist()),
                 pixel_center=validate.scalar(data.get("pixel_center", 0.0),
                                              f"{path}: 'pixel_center'"), **extra)


def detect(path):
  """Whether `path` is a file ending in .npz."""
  return os.path.isfile(path) and path.endswith(".npz")


def load(path, background, settings):
  """(train, test) of the .npz file `path` (`load_npz`), split at settings.holdout_from (-1:
  the reference's 80/20)."""
  return load_npz(path, background).split(settings.holdout_from)


FORMAT = formats.Format("npz", detect, load, expected="a .npz file", file=True)
