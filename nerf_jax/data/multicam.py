"""mip-NeRF's multiscale Blender format (its `Multicam` dataset): read and write.

A folder holds `metadata.json`: per split ('train', 'val', 'test') one list per field, an entry
per image: `file_path` (relative to the folder: `images_{split}/...png`), `cam2world` (4×4
camera-to-world, the Blender convention), `width`, `height`, `focal` (pixels), `label` (the
scale level j), `near`, `far`, `lossmult` (4^j: each scale's pixels weigh as much in the loss
as the full-size images') and `pix2cam` (3×3: pixel (x, y) + 0.5 to a camera direction, z =
-1). Rays pass through pixel centres. `convert_multiscale.py` converts a Blender folder to it.
"""

import json
import os

import imageio.v3 as iio
import numpy as np

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data import validate
from nerf_jax.data.dataset import DataError, Dataset

FILENAME = "metadata.json"
FIELDS = ("file_path", "cam2world", "width", "height", "focal", "label", "near", "far",
          "lossmult", "pix2cam")
SPLITS = ("train", "val", "test")


def pix2cam(focal, width, height):
  """float64 [3, 3] taking (x + 0.5, y + 0.5, 1) of pixel (x, y) to its camera direction."""
  return np.array([[1.0 / focal, 0.0, -0.5 * width / focal],
                   [0.0, -1.0 / focal, 0.5 * height / focal],
                   [0.0, 0.0, -1.0]])


def intrinsics_of(matrix, where):
  """(fx, fy, cx, cy) of a pix2cam matrix float [3, 3]; DataError unless it is a pinhole's."""
  m = np.asarray(matrix, np.float64)
  if m.shape != (3, 3) or not np.all(np.isfinite(m)) or m[0, 0] <= 0 or m[1, 1] >= 0 or (
      m[0, 1] != 0 or m[1, 0] != 0 or np.any(m[2] != [0, 0, -1])):
    raise DataError(f"{where}: not a pinhole pix2cam [[1/fx, 0, -cx/fx], [0, -1/fy, cy/fy], "
                    "[0, 0, -1]]")
  fx, fy = 1.0 / m[0, 0], -1.0 / m[1, 1]
  return fx, fy, -m[0, 2] * fx, m[1, 2] * fy


def _column(meta, key, count, where):
  values = meta.get(key)
  if not isinstance(values, list) or len(values) != count:
    raise DataError(f"{where}: '{key}' must be a list of {count} entries (one per image)")
  return values


def load(path, background=(0.0, 0.0, 0.0), split="train"):
  """The images of `split` of a multiscale folder (`path` holds metadata.json) as a Dataset
  with per-image cameras (`image_cameras`), `lossmult` and `labels` (str of `label`); RGBA is
  composited on `background` and its alpha becomes `accs`; near, far: the smallest near and
  largest far of the split's images."""
  meta_path = os.path.join(path, FILENAME)
  meta = validate.read_json(meta_path)
  if not isinstance(meta, dict) or not isinstance(meta.get(split), dict):
    raise DataError(f"{meta_path}: missing split {split!r}")
  meta, where = meta[split], f"{meta_path}: {split}"
  files = meta.get("file_path")
  if not isinstance(files, list) or not files:
    raise DataError(f"{where}: 'file_path' must be a non-empty list")
  count = len(files)
  for key in FIELDS:  # every list checked before any image is read
    if key in meta or key in ("cam2world", "width", "height", "focal"):
      _column(meta, key, count, where)
  col = lambda key: _column(meta, key, count, where)
  bg = validate.parse_background(background)
  images, accs, cameras = [], [], []
  for k, (name, width, height, focal) in enumerate(zip(files, col("width"), col("height"),
                                                         col("focal"))):
    if not os.path.isfile(os.path.join(path, name)):
      raise DataError(f"{where}: file_path[{k}]: image {os.path.join(path, name)} not found")
    image = validate.read_image(os.path.join(path, name))
    if image.shape[:2] != (height, width):
      raise DataError(f"{where}: image {k} ({name}) is {image.shape[1]}x{image.shape[0]}, "
                      f"metadata says {width}x{height}")
    intrinsics = ((float(focal), float(focal), 0.5 * width, 0.5 * height)
                  if "pix2cam" not in meta else intrinsics_of(col("pix2cam")[k],
                                                              f"{where}: pix2cam[{k}]"))
    cameras.append((int(height), int(width), intrinsics))
    rgba = image if image.shape[-1] == 4 else np.concatenate(
        [image, np.ones_like(image[..., :1])], -1)
    images.append(validate.composite(rgba, bg))
    accs.append(rgba[..., 3].astype(np.float32))
  poses = validate.poses(np.asarray(col("cam2world"), np.float64), f"{where}: 'cam2world'")
  if len({a.shape for a in images}) == 1:
    images, accs = np.stack(images), np.stack(accs)
  lossmult = np.asarray(col("lossmult") if "lossmult" in meta else np.ones(count), np.float32)
  labels = col("label") if "label" in meta else None
  near = min(col("near")) if "near" in meta else 2.0
  far = max(col("far")) if "far" in meta else 6.0
  return Dataset(images, poses, cameras[0][2], near=float(near), far=float(far), name=path,
                 accs=accs, background=tuple(bg.tolist()), pixel_center=0.5,
                 image_cameras=Cameras.stack(cameras), lossmult=lossmult, labels=labels)


def write(out_dir, splits):
  """Write `splits` ({split name: list of entries}) as a multiscale folder: each entry a dict
  with 'rgba' (float [H, W, 4] straight colour and alpha in [0, 1]), 'cam2world' (float [4, 4]),
  'focal', 'label' (int, or a str of digits, written as int; other str as they are), 'near',
  'far', 'lossmult'; images go to images_{split}/."""
  meta = {}
  for split, entries in splits.items():
    folder = f"images_{split}"
    os.makedirs(os.path.join(out_dir, folder), exist_ok=True)
    columns = {key: [] for key in FIELDS}
    for k, e in enumerate(entries):
      label = int(e["label"]) if str(e["label"]).isdigit() else str(e["label"])
      name = f"{folder}/{k:03d}_d{label}.png"
      iio.imwrite(os.path.join(out_dir, name),
                  np.round(np.clip(e["rgba"], 0.0, 1.0) * 255.0).astype(np.uint8))
      height, width = e["rgba"].shape[:2]
      row = {"file_path": name, "cam2world": np.asarray(e["cam2world"], np.float64).tolist(),
             "width": int(width), "height": int(height), "focal": float(e["focal"]),
             "label": label, "near": float(e["near"]), "far": float(e["far"]),
             "lossmult": float(e["lossmult"]),
             "pix2cam": pix2cam(e["focal"], width, height).tolist()}
      for key in FIELDS:
        columns[key].append(row[key])
    meta[split] = columns
  with open(os.path.join(out_dir, FILENAME), "w") as f:
    json.dump(meta, f)
