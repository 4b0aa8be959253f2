"""Dataset loaders: tiny_nerf .npz, NeRF-synthetic (Blender) folders, and built-in scenes.

Every malformed input raises `DataError` with a one-line message naming the file and field.
"""

import json
import math
import os
import zipfile

import imageio.v3 as iio
import numpy as np

from nerf_jax import scenes
from nerf_jax.data.dataset import DataError, Dataset

_BACKGROUNDS = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0),
                "random": (0.0, 0.0, 0.0)}  # 'random': the trainer re-composites per step


def parse_background(background):
  """'black', 'white', 'random' or an RGB triple in [0, 1] -> float64 [3]."""
  if isinstance(background, str):
    if background not in _BACKGROUNDS:
      raise DataError(f"background: unknown name {background!r} (valid: black, white, random, "
                      "or an RGB triple)")
    return np.array(_BACKGROUNDS[background])
  rgb = np.asarray(background, np.float64)
  if rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 1)):
    raise DataError(f"background: expected an RGB triple in [0, 1], got {background!r}")
  return rgb


def composite(rgba, background):
  """rgba: float [..., 3 or 4] straight (unpremultiplied) colour -> float32 [..., 3]."""
  if rgba.shape[-1] == 3:
    return rgba.astype(np.float32)
  alpha = rgba[..., 3:]
  return (rgba[..., :3] * alpha + background * (1.0 - alpha)).astype(np.float32)


def _unit_images(images, where):
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


def _floats(value, where):
  try:
    return np.asarray(value, np.float64)
  except (TypeError, ValueError):
    raise DataError(f"{where}: not numeric ({str(value)[:40]})") from None


def _poses(poses, where):
  """[N, 3, 4] or [N, 4, 4] camera-to-world -> float32 [N, 4, 4]."""
  poses = _floats(poses, where)
  if poses.ndim != 3 or poses.shape[1:] not in ((3, 4), (4, 4)):
    raise DataError(f"{where}: shape {poses.shape}; expected [N, 4, 4] or [N, 3, 4]")
  if not np.all(np.isfinite(poses)):
    raise DataError(f"{where}: contains NaN or inf")
  bottom = np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(poses), 1, 4))
  return np.concatenate([poses[:, :3], bottom], 1).astype(np.float32)


def _scalar(value, where):
  value = _floats(value, where)
  if value.size != 1 or not np.isfinite(value).all():
    raise DataError(f"{where}: expected one finite number, got shape {value.shape}")
  return float(value.reshape(()))


def load_npz(path, background=(0.0, 0.0, 0.0)):
  """The tiny_nerf format: `images` [N, H, W, 3|4], `poses` [N, 4|3, 4], `focal`; optional
  `near`, `far` (default 2, 6) and ground-truth `depths`, `accs`. RGBA is composited on
  `background` (see `parse_background`). Returns a Dataset."""
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
  images = _unit_images(data["images"], f"{path}: 'images'")
  if images.ndim != 4:
    raise DataError(f"{path}: 'images' has shape {images.shape}; expected [N, H, W, 3 or 4]")
  poses = _poses(data["poses"], f"{path}: 'poses'")
  if len(poses) != len(images):
    raise DataError(f"{path}: 'images' has {len(images)} views but 'poses' has {len(poses)}")
  focal = _scalar(data["focal"], f"{path}: 'focal'")
  num, height, width = images.shape[:3]
  extra = {k: data[k].astype(np.float32) for k in ("depths", "accs")
           if k in data and data[k].shape == (num, height, width)}
  return Dataset(composite(images, parse_background(background)), poses,
                 (focal, focal, width * 0.5, height * 0.5),
                 near=_scalar(data.get("near", 2.0), f"{path}: 'near'"),
                 far=_scalar(data.get("far", 6.0), f"{path}: 'far'"), name=path, **extra)


def _read_json(path):
  if not os.path.isfile(path):
    raise DataError(f"{path}: no such file")
  with open(path) as f:
    try:
      return json.load(f)
    except json.JSONDecodeError as e:
      raise DataError(f"{path}: malformed JSON at line {e.lineno} column {e.colno}: "
                      f"{e.msg}") from None


def _field(obj, key, where):
  if not isinstance(obj, dict) or key not in obj:
    raise DataError(f"{where}: missing key {key!r}")
  return obj[key]


def _read_frame(root, meta_path, k, frame):
  """One frame's (float64 [H, W, 3|4] image, float [4, 4] pose)."""
  where = f"{meta_path}: frames[{k}]"
  image_path = os.path.join(root, _field(frame, "file_path", where))
  if not os.path.isfile(image_path) and os.path.isfile(image_path + ".png"):
    image_path += ".png"
  if not os.path.isfile(image_path):
    raise DataError(f"{where}.file_path: image {image_path} not found")
  try:
    image = iio.imread(image_path)
  except Exception as e:  # imageio raises many types for unreadable files
    raise DataError(f"{image_path}: cannot read image ({e})") from None
  pose = np.asarray(_field(frame, "transform_matrix", where), np.float64)[None]
  return _unit_images(image, image_path), _poses(pose, f"{where}.transform_matrix")[0]


def _half_res(rgba):
  """2x2 area average of float64 [N, H, W, 4] straight-alpha images (premultiplied while
  averaging so that transparent pixels' colours do not bleed); odd sizes lose a row/column."""
  num, height, width = rgba.shape[0], rgba.shape[1] // 2, rgba.shape[2] // 2
  premult = np.concatenate([rgba[..., :3] * rgba[..., 3:], rgba[..., 3:]], -1)
  blocks = premult[:, :2 * height, :2 * width].reshape(num, height, 2, width, 2, 4)
  mean = blocks.mean((2, 4))
  alpha = mean[..., 3:]
  return np.concatenate([mean[..., :3] / np.maximum(alpha, 1e-12), alpha], -1)  # 0/0 -> 0


def load_blender(path, background=(0.0, 0.0, 0.0), half_res=False, split="train"):
  """A NeRF-synthetic folder: `transforms_{split}.json` with `camera_angle_x` and `frames`
  (`file_path` relative to `path`, with or without '.png'; `transform_matrix` 4x4), optional
  `near`/`far` (default 2, 6). RGBA PNGs are composited on `background`. Returns a Dataset."""
  meta_path = os.path.join(path, f"transforms_{split}.json")
  meta = _read_json(meta_path)
  angle = _scalar(_field(meta, "camera_angle_x", meta_path), f"{meta_path}: 'camera_angle_x'")
  frames = _field(meta, "frames", meta_path)
  if not isinstance(frames, list) or not frames:
    raise DataError(f"{meta_path}: 'frames' must be a non-empty list")
  images, poses = zip(*(_read_frame(path, meta_path, k, f) for k, f in enumerate(frames)))
  shapes = {im.shape[:2] for im in images}
  if len(shapes) > 1:
    raise DataError(f"{meta_path}: images have different sizes {sorted(shapes)}")
  width = images[0].shape[1]
  focal = 0.5 * width / math.tan(0.5 * angle)
  rgba = np.stack([im if im.shape[-1] == 4 else np.concatenate(
      [im, np.ones_like(im[..., :1])], -1) for im in images])
  if half_res:
    rgba, focal = _half_res(rgba), 0.5 * focal
  height, width = rgba.shape[1:3]
  return Dataset(composite(rgba, parse_background(background)), np.stack(poses),
                 (focal, focal, width * 0.5, height * 0.5),
                 near=_scalar(meta.get("near", 2.0), f"{meta_path}: 'near'"),
                 far=_scalar(meta.get("far", 6.0), f"{meta_path}: 'far'"), name=path)


def load_dataset(config):
  """(train, test) Datasets from a `data` ConfigDict (or dict).

  Fields (all optional): path ('' = built-in `scene`), scene, holdout_from (-1 = 80/20; ignored
  for Blender, which has its own test split), num_views, image_size and pixel_center (built-in
  only; focal keeps tiny_nerf's field of view), background and half_res (files only).
  """
  path = config.get("path", "") or ""
  holdout_from = config.get("holdout_from", -1)
  background = parse_background(config.get("background", "black"))
  if not path:
    name, size = config.get("scene", "diffuse"), config.get("image_size", 100)
    if name not in scenes.SCENES:
      raise DataError(f"data.scene: unknown scene {name!r} (valid: {', '.join(scenes.SCENES)})")
    dataset = scenes.make_dataset(
        name, num_views=config.get("num_views", 100), height=size, width=size,
        focal=scenes.TINY_NERF_FOCAL * size / 100, pixel_center=config.get("pixel_center", 0.0))
    return dataset.split(holdout_from)
  if not os.path.exists(path):
    raise DataError(f"{path}: no such file or directory")
  if os.path.isfile(path) and path.endswith(".npz"):
    return load_npz(path, background).split(holdout_from)
  if os.path.isfile(os.path.join(path, "transforms_train.json")):
    half_res = config.get("half_res", False)
    return tuple(load_blender(path, background, half_res, s) for s in ("train", "test"))
  raise DataError(f"unknown dataset format at {path} (expected a .npz file or a directory with "
                  "transforms_train.json)")
