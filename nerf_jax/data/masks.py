"""Per-pixel masks: which pixels of a photo are the scene (kept) and which are not (ignored).

A mask is float32 [H, W] of 0 (ignore: a passer-by, a car, the photographer's shadow) and 1
(keep), the size of its image (`Dataset.masks`). Masks are read as users already store them:
  nerfstudio   frames[].mask_path: a grey image, 0 = ignore, anything else keep ('nonzero');
  instant-ngp  dynamic_mask_<image stem>.png beside the image: non-zero = dynamic, so ignore
               ('dynamic');
  LLFF, COLMAP a masks/ folder beside images/, same file names (or the name with '.png' added
               or in place of its extension): white = keep, from half grey ('white').
A mask is made smaller with its image by `downscale` (and resampled by `resample`) so that a
pixel is kept only if its whole footprint is kept: masked content never leaks into a kept pixel.
"""

import os

import numpy as np

from nerf_jax.data import lens, validate
from nerf_jax.data.dataset import DataError

MASKS_DIR = "masks"  # the LLFF / COLMAP folder beside images/
DYNAMIC_PREFIX = "dynamic_mask_"  # instant-ngp's mask files beside the images
# How a mask file's grey value g in [0, 1] says keep: see the module docstring.
RULES = {"nonzero": lambda g: g > 0.0, "dynamic": lambda g: g <= 0.0,
         "white": lambda g: g >= 0.5}
KEPT = 1.0 - 1e-6  # a resampled mask keeps a pixel only if all its neighbours are kept (~1)


def read(path, rule, where):
  """The mask in the image file `path` as float32 [H, W] of 0 and 1; `rule`: a key of RULES;
  an RGB(A) file is read by its first channel. DataError naming `where` if it is missing."""
  if not os.path.isfile(path):
    raise DataError(f"{where}: mask {path} not found")
  return RULES[rule](validate.read_grey(path)).astype(np.float32)


def downscale(mask, factor):
  """mask float32 [H, W] at 1/factor (integer) of its size, as images are block-averaged (odd
  edges cropped): a block is kept only if every pixel of it is (a min pool)."""
  if factor == 1:
    return mask
  height, width = mask.shape[0] // factor, mask.shape[1] // factor
  blocks = mask[:height * factor, :width * factor]
  return blocks.reshape(height, factor, width, factor).min((1, 3))


def resample(mask, intrinsics, dist, target_intrinsics, target_size):
  """mask float32 [H, W] resampled as `lens.resample` resamples its image: a pixel is kept only
  where the bilinear weights fall on kept pixels alone (value ~1, `KEPT`)."""
  value = lens.resample(mask[..., None], intrinsics, dist, target_intrinsics, target_size)[..., 0]
  return (value >= KEPT).astype(np.float32)


def check(mask, image_shape, where):
  """`mask` (float32 [H, W]) unless it is the wrong size for an image of `image_shape` ([H, W,
  ...]) or masks every pixel: then DataError naming `where`."""
  if mask.shape != tuple(image_shape[:2]):
    raise DataError(f"{where}: mask is {mask.shape[1]}x{mask.shape[0]} but its image is "
                    f"{image_shape[1]}x{image_shape[0]}")
  if not mask.any():
    raise DataError(f"{where}: the mask ignores every pixel of its image")
  return mask


def folder_mask_path(masks_dir, image_name):
  """The file in `masks_dir` masking the image `image_name`: the same name, the name with '.png'
  added, or with '.png' in place of its extension; None when there is none."""
  stem = os.path.splitext(image_name)[0]
  for name in (image_name, image_name + ".png", stem + ".png"):
    path = os.path.join(masks_dir, name)
    if os.path.isfile(path):
      return path
  return None


def folder_masks(folder, names):
  """The masks of the images `names` (file names in `folder`/images/ or the folder itself)
  from the masks/ folder beside them: a list of float32 [H, W] at the images' full size, or
  None without a masks/ folder. DataError naming the image whose mask is missing."""
  masks_dir = os.path.join(folder, MASKS_DIR)
  if not os.path.isdir(masks_dir):
    return None
  masks = []
  for name in names:
    path = folder_mask_path(masks_dir, name)
    if path is None:
      raise DataError(f"{masks_dir}: no mask for image {name} (looked for {name}, {name}.png "
                      f"and {os.path.splitext(name)[0]}.png)")
    masks.append(read(path, "white", path))
  return masks


def dynamic_mask_path(image_path):
  """instant-ngp's mask of the image at `image_path`: dynamic_mask_<stem>.png beside it, or
  None when there is none."""
  folder, name = os.path.split(image_path)
  path = os.path.join(folder, DYNAMIC_PREFIX + os.path.splitext(name)[0] + ".png")
  return path if os.path.isfile(path) else None


def write(path, mask):
  """Write mask float32 [H, W] as an 8-bit grey PNG, 255 = keep, 0 = ignore (what 'nonzero' and
  'white' read back)."""
  import imageio.v3 as iio  # pylint: disable=import-outside-toplevel
  os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
  iio.imwrite(path, np.where(np.asarray(mask) > 0.5, 255, 0).astype(np.uint8))


def kept_share(masks):
  """The share of pixels kept by masks (float32 [N, H, W] or a list of [H_i, W_i]): float."""
  masks = [np.asarray(m) for m in masks]
  return float(sum(m.sum() for m in masks) / sum(m.size for m in masks))
