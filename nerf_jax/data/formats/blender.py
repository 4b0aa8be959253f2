"""The NeRF-synthetic (Blender) format: a folder of `transforms_{split}.json` files and the
images they name, for the splits 'train' and 'test'."""

import math
import os

import numpy as np

from nerf_jax.data import formats, masks as masks_lib, resampling, validate
from nerf_jax.data.data_settings import DataSettings
from nerf_jax.data.dataset import DataError, Dataset
from nerf_jax.data.validate import composite, parse_background

TRAIN_FILE = "transforms_train.json"  # what marks a Blender folder


def _field(obj, key, where):
  if not isinstance(obj, dict) or key not in obj:
    raise DataError(f"{where}: missing key {key!r}")
  return obj[key]


def _frame_image_path(root, meta_path, k, frame):
  """The path of one frame's image (file_path, with or without '.png')."""
  where = f"{meta_path}: frames[{k}]"
  image_path = os.path.join(root, _field(frame, "file_path", where))
  if not os.path.isfile(image_path) and os.path.isfile(image_path + ".png"):
    image_path += ".png"
  if not os.path.isfile(image_path):
    raise DataError(f"{where}.file_path: image {image_path} not found")
  return image_path


def _read_frame(root, meta_path, k, frame):
  """One frame's (float64 [H, W, 3|4] image, float32 [4, 4] pose)."""
  where = f"{meta_path}: frames[{k}]"
  image_path = _frame_image_path(root, meta_path, k, frame)
  pose = np.asarray(_field(frame, "transform_matrix", where), np.float64)[None]
  return validate.read_image(image_path), validate.poses(pose, f"{where}.transform_matrix")[0]


def _read_frame_mask(root, meta_path, k, frame, image_path):
  """One frame's mask float32 [H, W] (data/masks.py) or None: frames[].mask_path (nerfstudio's,
  0 = ignore), else instant-ngp's dynamic_mask_<stem>.png beside the image."""
  where = f"{meta_path}: frames[{k}]"
  if frame.get("mask_path"):
    path = os.path.join(root, frame["mask_path"])
    if not os.path.isfile(path) and os.path.isfile(path + ".png"):
      path += ".png"
    return masks_lib.read(path, "nonzero", f"{where}.mask_path")
  path = masks_lib.dynamic_mask_path(image_path)
  return None if path is None else masks_lib.read(path, "dynamic", path)


def _half_res(rgba):
  """2x2 area average of float64 [N, H, W, 4] straight-alpha images (premultiplied while
  averaging so that transparent pixels' colours do not bleed); odd sizes lose a row/column."""
  premult = np.concatenate([rgba[..., :3] * rgba[..., 3:], rgba[..., 3:]], -1)
  mean = resampling.block_mean(premult, 2)
  alpha = mean[..., 3:]
  return np.concatenate([mean[..., :3] / np.maximum(alpha, 1e-12), alpha], -1)  # 0/0 -> 0


def load_blender(path, background=(0.0, 0.0, 0.0), half_res=DataSettings.half_res,
                 split="train"):
  """A NeRF-synthetic folder: `transforms_{split}.json` with `camera_angle_x` and `frames`
  (`file_path` relative to `path`, with or without '.png'; `transform_matrix` 4x4), optional
  `near`/`far` (default 2, 6). RGBA PNGs are composited on `background`; `accs` is their alpha
  (1 for RGB PNGs). Rendered images: pixel_center 0.5. Masks (data/masks.py): frames[].mask_path
  or instant-ngp's dynamic_mask_<stem>.png, min-pooled with half_res. Returns a Dataset."""
  meta_path = os.path.join(path, f"transforms_{split}.json")
  meta = validate.read_json(meta_path)
  angle = validate.scalar(_field(meta, "camera_angle_x", meta_path),
                          f"{meta_path}: 'camera_angle_x'")
  frames = _field(meta, "frames", meta_path)
  if not isinstance(frames, list) or not frames:
    raise DataError(f"{meta_path}: 'frames' must be a non-empty list")
  bg = parse_background(background)
  poses, size, masks = [], None, []
  # One frame at a time into float32 arrays: the float64 copies of a frame live only while it
  # is converted, so 100 frames of 800 x 800 need ~1 GB, not several.
  for k, frame in enumerate(frames):
    image, pose = _read_frame(path, meta_path, k, frame)
    if size is None:
      size = image.shape[:2]
      focal = 0.5 * size[1] / math.tan(0.5 * angle) * (0.5 if half_res else 1.0)
    elif image.shape[:2] != size:
      raise DataError(f"{meta_path}: images have different sizes {sorted({size, image.shape[:2]})}")
    rgba = image if image.shape[-1] == 4 else np.concatenate([image, np.ones_like(image[..., :1])],
                                                             -1)
    if half_res:
      rgba = _half_res(rgba[None])[0]
    if k == 0:
      images = np.empty((len(frames), *rgba.shape[:2], 3), np.float32)
      accs = np.empty((len(frames), *rgba.shape[:2]), np.float32)
    images[k], accs[k] = composite(rgba, bg), rgba[..., 3]
    poses.append(pose)
    mask = _read_frame_mask(path, meta_path, k, frame, _frame_image_path(path, meta_path, k,
                                                                          frame))
    if mask is not None:
      mask = masks_lib.check(masks_lib.downscale(mask, 2) if half_res else mask,
                             rgba.shape, f"{meta_path}: frames[{k}]")
    masks.append(mask)
  height, width = images.shape[1:3]
  return Dataset(images, np.stack(poses), (focal, focal, width * 0.5, height * 0.5),
                 near=validate.scalar(meta.get("near", 2.0), f"{meta_path}: 'near'"),
                 far=validate.scalar(meta.get("far", 6.0), f"{meta_path}: 'far'"), name=path,
                 accs=accs, background=tuple(bg.tolist()),
                 masks=None if all(m is None for m in masks) else np.stack(
                     [np.ones((height, width), np.float32) if m is None else m for m in masks]))


def detect(path):
  """Whether the folder `path` holds transforms_train.json."""
  return os.path.isfile(os.path.join(path, TRAIN_FILE))


def load(path, background, settings):
  """(train, test): the folder's own splits (`load_blender`; settings.half_res applies,
  settings.holdout_from does not)."""
  return tuple(load_blender(path, background, settings.half_res, s) for s in ("train", "test"))


def background(path):
  """'white' for a folder of RGBA images (the first training frame's image decides), the
  convention every published table scores Blender's data on; None (black) for RGB images."""
  meta_path = os.path.join(path, TRAIN_FILE)
  frames = validate.read_json(meta_path).get("frames")
  if isinstance(frames, list) and frames:  # else load_blender says what is wrong
    image_path = _frame_image_path(path, meta_path, 0, frames[0])
    if validate.read_image(image_path).shape[-1] == 4:
      return "white", "the convention of Blender (NeRF-synthetic) data"
  return None


FORMAT = formats.Format("blender", detect, load, background, expected=TRAIN_FILE)
