"""Convert a NeRF-synthetic (Blender) folder to mip-NeRF's multiscale format (`multicam.py`),
as google/mipnerf's `scripts/convert_blender_data.py` does:

  python -m nerf_jax.data.convert_multiscale --blender=DIR --out=DIR [--levels=4]

Every view is written at `levels` scales: level j + 1 is the 2×2 box mean in float of level j's
straight (un-premultiplied) RGBA as stored (as mip-NeRF does; an odd last row or column is
dropped), focal / 2^j, lossmult 4^j, label j; each level is saved as 8-bit PNG (rounded to the
nearest value).
"""

import argparse
import json
import math
import os
import sys

import numpy as np

from nerf_jax.data import multicam, resampling, validate
from nerf_jax.data.dataset import DataError


def convert(blender_dir, out_dir, levels=4):
  """Convert the Blender folder `blender_dir` (transforms_{split}.json, RGBA or RGB PNGs) to a
  multiscale folder `out_dir` with `levels` scales (module docstring); returns {split: number
  of images written}."""
  if levels < 1:
    raise DataError(f"--levels={levels}: use 1 or more")
  splits = {}
  for split in multicam.SPLITS:
    meta_path = os.path.join(blender_dir, f"transforms_{split}.json")
    if not os.path.isfile(meta_path):
      continue
    with open(meta_path) as f:
      meta = json.load(f)
    entries = []
    for k, frame in enumerate(meta["frames"]):
      image_path = os.path.join(blender_dir, frame["file_path"])
      if not os.path.isfile(image_path):
        image_path += ".png"
      rgba = validate.read_image(image_path)
      if rgba.shape[-1] == 3:
        rgba = np.concatenate([rgba, np.ones_like(rgba[..., :1])], -1)
      focal = 0.5 * rgba.shape[1] / math.tan(0.5 * float(meta["camera_angle_x"]))
      for j in range(levels):
        entries.append({"rgba": rgba, "cam2world": frame["transform_matrix"],
                        "focal": focal / 2 ** j, "label": j, "lossmult": 4.0 ** j,
                        "near": meta.get("near", 2.0), "far": meta.get("far", 6.0)})
        rgba = resampling.block_mean(rgba, 2)
    splits[split] = entries
  if not splits:
    raise DataError(f"{blender_dir}: no transforms_{{train,val,test}}.json")
  multicam.write(out_dir, splits)
  return {split: len(entries) for split, entries in splits.items()}


def main(argv=None):
  parser = argparse.ArgumentParser(description="Convert a Blender folder to mip-NeRF's "
                                   "multiscale format.")
  parser.add_argument("--blender", required=True, help="NeRF-synthetic (Blender) folder")
  parser.add_argument("--out", required=True, help="multiscale folder to write")
  parser.add_argument("--levels", type=int, default=4, help="scales: full, 1/2, 1/4, ...")
  args = parser.parse_args(argv)
  try:
    written = convert(args.blender, args.out, args.levels)
  except (ValueError, OSError, KeyError) as e:  # DataError is a ValueError
    print(f"error: {e}", file=sys.stderr)
    return 1
  print(f"wrote {', '.join(f'{n} {s}' for s, n in written.items())} images to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
