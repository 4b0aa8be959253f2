"""Dataset loaders: tiny_nerf .npz, NeRF-synthetic (Blender), mip-NeRF multiscale, LLFF and
COLMAP folders, built-in scenes.

Every malformed input raises `DataError` with a one-line message naming the file and field.
Every loader fills `Dataset.accs` and `Dataset.background` where the input tells them: RGBA
images give the opacity (alpha) and are composited on the `background` argument.
"""

import dataclasses
import math
import os
import zipfile
from typing import Any

import numpy as np

from nerf_jax.data import scenes
from nerf_jax.data import colmap, masks as masks_lib, multicam, nerfstudio, validate
from nerf_jax.data.dataset import DataError, Dataset
from nerf_jax.data.llff import load_llff
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
  num, height, width = rgba.shape[0], rgba.shape[1] // 2, rgba.shape[2] // 2
  premult = np.concatenate([rgba[..., :3] * rgba[..., 3:], rgba[..., 3:]], -1)
  blocks = premult[:, :2 * height, :2 * width].reshape(num, height, 2, width, 2, 4)
  mean = blocks.mean((2, 4))
  alpha = mean[..., 3:]
  return np.concatenate([mean[..., :3] / np.maximum(alpha, 1e-12), alpha], -1)  # 0/0 -> 0


def load_blender(path, background=(0.0, 0.0, 0.0), half_res=False, split="train"):
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


@dataclasses.dataclass(frozen=True)
class DataSettings:
  """What `load_dataset` loads: config.data's fields of the images and cameras (the rest of
  config.data, how rays see the scene, is run/settings.SceneSettings)."""
  path: str = ""  # dataset: .npz, Blender, LLFF, transforms.json or COLMAP folder; '' = built-in
  scene: str = "diffuse"  # built-in scene name (data/scenes)
  num_views: int = 100  # built-in scene: number of rendered views
  image_size: int = 100  # built-in scene: height = width in pixels
  holdout_from: int = -1  # views[holdout_from:] are test views; -1 = the format's own split
  held_out_looks: str = "neutral"  # per-photo-look scenes: test views 'neutral' or 'own' looks
  pixel_center: float = -1.0  # -1 = the data's own (0.5 centres; 0 corners for tiny_nerf .npz)
  background: Any = "auto"  # 'auto' (white for Blender data, else black), 'black', 'white' or RGB
  half_res: bool = False  # Blender data: load at half resolution
  factor: int = 1  # LLFF, transforms.json and COLMAP data: downsample images by this factor
  bd_factor: float = 0.75  # LLFF data: scale so the nearest bound is 1/bd_factor (0 = keep units)
  recenter: bool = True  # LLFF data: move the mean camera pose to the origin
  min_sharpness: float = 0.0  # transforms.json: drop frames < this x neighbours' sharpness (0 = off)
  without: str = ""  # built-in scene: capture effects left out, e.g. 'zoom,distortion' (the truth)


def auto_background(path):
  """(name, why): the background data.background='auto' means for the data at `path` ('' = a
  built-in scene), the convention of its family: 'white' for a Blender (NeRF-synthetic) folder
  of RGBA images (transforms_train.json; the first frame's image decides) and for a mip-NeRF
  multiscale folder of RGBA images (metadata.json, made from Blender's; the first training
  image decides), on which every published table scores that data; 'black' for everything else
  (built-in scenes, .npz, LLFF, transforms.json and COLMAP folders, Blender and multiscale
  folders of RGB images)."""
  is_file = lambda name: bool(path) and os.path.isfile(os.path.join(path, name))
  if not path or not os.path.isdir(path) or is_file(nerfstudio.FILENAME):
    return "black", "the convention of data other than Blender's RGBA folders"
  if is_file(multicam.FILENAME):  # read before transforms_train.json (load_dataset's order)
    if _first_multiscale_image_channels(path) == 4:
      return "white", "the convention of mip-NeRF's multiscale data (Blender's RGBA, on white)"
  elif is_file("transforms_train.json"):
    meta_path = os.path.join(path, "transforms_train.json")
    frames = validate.read_json(meta_path).get("frames")
    if isinstance(frames, list) and frames:  # else load_blender says what is wrong
      image_path = _frame_image_path(path, meta_path, 0, frames[0])
      if validate.read_image(image_path).shape[-1] == 4:
        return "white", "the convention of Blender (NeRF-synthetic) data"
  return "black", "the convention of data other than Blender's RGBA folders"


def _first_multiscale_image_channels(path):
  """The channels of the first training image a multiscale folder's metadata.json names, or
  None where it names none that exists (multicam.load then says what is wrong)."""
  meta = validate.read_json(os.path.join(path, multicam.FILENAME))
  train = meta.get("train") if isinstance(meta, dict) else None
  files = train.get("file_path") if isinstance(train, dict) else None
  if not isinstance(files, list) or not files or not isinstance(files[0], str):
    return None
  image_path = os.path.join(path, files[0])
  return validate.read_image(image_path).shape[-1] if os.path.isfile(image_path) else None


def is_auto(background):
  """Whether a data.background value is 'auto' (resolved from the data: `auto_background`)."""
  return isinstance(background, str) and background == "auto"


def load_dataset(settings):
  """(train, test) Datasets as `settings` (DataSettings) say.

  path '' = the built-in `scene` (image_size, num_views and pixel_center apply, -1 = 0.5; focal
  keeps tiny_nerf's field of view; held_out_looks 'own' gives the test views of a scene with
  per-photo looks their own, scenes/photos.py); background ('auto': `auto_background`) and
  half_res apply to .npz and Blender; factor, bd_factor (0 = keep the file's units) and
  recenter to LLFF, see `load_llff`: the defaults are the original NeRF's LLFF pipeline, which
  NDC rays (near plane 1, world -z forward) rely on.
  holdout_from: views[holdout_from:] are the test views; -1 = the default split of the format:
  the reference's 80/20 for built-in scenes and .npz, every 8th view (0, 8, 16, ...) for LLFF
  (the original NeRF's convention), for COLMAP folders (`colmap.load_split`) and for
  transforms.json folders unless the file names its test images (`nerfstudio.load_split`);
  Blender folders and mip-NeRF's multiscale folders (metadata.json, `multicam.load`:
  per-image cameras) have their own test split and ignore it.
  factor also downscales transforms.json folders (nerfstudio / nerf-process output) and COLMAP
  folders (images/ and sparse/0/, `colmap.load`), and min_sharpness drops transforms.json's
  blurry frames. A folder with poses_bounds.npy is read as LLFF even with a COLMAP model beside
  it (LLFF's own data has both).
  """
  path, holdout_from = settings.path, settings.holdout_from
  background = parse_background(auto_background(path)[0] if is_auto(settings.background)
                                else settings.background)
  if not path:
    name, size = settings.scene, settings.image_size
    if name not in scenes.SCENES:
      raise DataError(f"data.scene: unknown scene {name!r} (valid: {', '.join(scenes.SCENES)})")
    try:
      effects, lens_parts = scenes.without(scenes.get_scene(name).effects, settings.without)
    except ValueError as error:
      raise DataError(str(error)) from None
    dataset = scenes.make_dataset(
        name, num_views=settings.num_views, height=size, width=size,
        focal=scenes.TINY_NERF_FOCAL * size / 100,
        pixel_center=0.5 if settings.pixel_center == -1 else settings.pixel_center)
    train, test = dataset.split(holdout_from)
    if settings.held_out_looks not in ("neutral", "own"):
      raise DataError(f"data.held_out_looks={settings.held_out_looks!r}: use 'neutral' or 'own'")
    if settings.held_out_looks == "own":
      test = scenes.held_out_with_own_looks(test, effects, len(train))
    return scenes.photographed(train, effects, lens_parts=lens_parts), test
  if not os.path.exists(path):
    raise DataError(f"{path}: no such file or directory")
  if os.path.isfile(path) and path.endswith(".npz"):
    return load_npz(path, background).split(holdout_from)
  if path.endswith(nerfstudio.FILENAME) or os.path.isfile(os.path.join(path, nerfstudio.FILENAME)):
    return nerfstudio.load_split(path, background, settings.factor or 1, holdout_from,
                                 settings.min_sharpness)
  if os.path.isfile(os.path.join(path, multicam.FILENAME)):
    return tuple(multicam.load(path, background, s) for s in ("train", "test"))
  if os.path.isfile(os.path.join(path, "transforms_train.json")):
    return tuple(load_blender(path, background, settings.half_res, s) for s in ("train", "test"))
  if os.path.isfile(os.path.join(path, "poses_bounds.npy")):
    dataset = load_llff(path, factor=settings.factor or 1, bd_factor=settings.bd_factor or None,
                        recenter=settings.recenter)
    return dataset.split_every(8) if holdout_from == -1 else dataset.split(holdout_from)
  if os.path.isdir(path) and colmap.model_dir(path):
    return colmap.load_split(path, background, settings.factor or 1, holdout_from)
  raise DataError(f"unknown dataset format at {path} (expected a .npz file or a directory with "
                  "transforms.json, transforms_train.json, poses_bounds.npy or a COLMAP model "
                  f"in {' or '.join(colmap.MODEL_DIRS)})")
