"""The size `--config=auto` trains photos at: data.factor, decided before any photo is read,
from the photos' sizes in their file headers (imageio's `improps` reads no pixels).

It applies to the folders that data.factor downscales, LLFF (`poses_bounds.npy` and `images/`)
and transforms.json (nerfstudio, instant-ngp, nerf-process), whose photos their format names
(`photo_paths`, data/formats/), and only where the user set no data.factor: a 12-megapixel
phone photo read at full size is 145 MB as float32, so a hundred of them do not fit in a
laptop's memory, and every held-out view and video frame renders each of its pixels.
"""

import imageio.v3 as iio

from nerf_jax.data import formats
from nerf_jax.run import config_lib

# The longest side, in pixels, auto trains photos at on each backend (`for_backend`'s 'cpu' for
# every backend but 'gpu'). Unmeasured choices: the CPU configs were measured on photos of at
# most 504 px a side (fern's images_8, fox at factor 4: docs/real_captures.md); 1,024 px keeps a
# hundred photos under 1 GB as float32 and a 12 MP photo (4032 x 3024) at factor 4, LLFF's and
# nerfstudio's images_4. A GPU holds and renders four times the pixels in the same time budget.
MAX_SIDE = {"cpu": 1024, "gpu": 2048}


def largest_photo(paths):
  """(width, height) of the photo with the longest side among `paths` (image files), read
  from their headers; None when there are none."""
  sizes = [iio.improps(p).shape[:2][::-1] for p in paths]
  return max(sizes, key=max) if sizes else None


def factor_for(width, height, max_side):
  """The smallest integer factor f >= 1 with max(width, height) // f <= max_side."""
  side = max(width, height)
  return max(1, -(-side // max_side))  # ceil(side / max_side)


def factor_effects(config, backend):
  """({'data.factor': f}, [line]) for `config` (config.auto, data.path a folder of photos) on
  `backend` ('cpu', 'gpu', ...): f the smallest integer factor that brings the largest photo's
  longest side to at most MAX_SIDE; one line saying why (or that the photos stay at full
  size). ({}, []) where the data is not such a folder. A data.factor the user set (named in
  config.auto_flags or differing from 1, configs/auto.py's) is theirs: not decided, and one
  line says so where auto's would differ. auto_config records the lines with its own."""
  paths = formats.photo_paths(config.data.path)  # the format's (data/formats/)
  size = largest_photo(paths) if paths else None
  if size is None:
    return {}, []
  width, height = size
  max_side = MAX_SIDE["gpu" if backend == "gpu" else "cpu"]
  factor = factor_for(width, height, max_side)
  photos = f"the photos are {width} x {height} ({width * height / 1e6:.3g} MP)"
  if ("data.factor" in config.auto_flags
      or config.data.factor != config_lib.load("auto").data.factor):
    if config.data.factor == factor:
      return {}, []
    return {}, [f"data.factor={config.data.factor!r} from your flags, not auto's {factor!r} "
                f"({photos})"]
  limit = f"{max_side} px a side on the {backend} backend (MAX_SIDE)"
  if factor == 1:
    return {"data.factor": 1}, [f"data.factor=1: {photos}, full size (<= {limit})"]
  return {"data.factor": factor}, [
      f"data.factor={factor}: {photos}; the smallest integer factor that brings them to "
      f"{width // factor} x {height // factor} (> {limit} at full size)"]
