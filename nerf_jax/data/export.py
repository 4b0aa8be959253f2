"""Write a Dataset as a tiny_nerf .npz, a NeRF-synthetic (Blender) folder, an LLFF folder or a
mip-NeRF multiscale folder (per-image cameras; the other formats store one camera and refuse
data with cameras of their own in one line).

  python -m nerf_jax.data.export --scene=fog --format=blender --out=/tmp/fog [--alpha]
  python -m nerf_jax.data.export --scene=multiscale --format=multiscale --out=/tmp/ms
  python -m nerf_jax.data.export --scene=white --format=npz --out=/tmp/white.npz [--rgb_only]
  python -m nerf_jax.data.export --scene=forward --format=llff --out=/tmp/forward
  python -m nerf_jax.data.export --scene=landmark --format=llff --out=/tmp/landmark

A scene with capture effects (`scenes.scene.CAPTURE`: per-photo looks, passers-by, pose errors,
per-photo lenses) is written as `load_dataset` gives it: the first 80% of the views are the
photographed training views (scenes/photos.py), the rest the held-out ground truth (an LLFF
folder holds out every 8th view: load it with data.holdout_from at 80% to hold out the same).

PNG alpha: by default every pixel is opaque (alpha = 255) and holds the composited image, so that
`load_blender` returns the same images (to 8-bit quantisation, 1/255) with any `background`.
Masks (`Dataset.masks`) travel in every format: the npz's `masks` array, Blender's
frames[].mask_path (`{split}/r_{k}_mask.png`, 255 keep, 0 ignore), LLFF's masks/ folder.
With `background` given (and ground-truth `accs`), alpha = opacity and the colour is the
unpremultiplied emission, as in the original NeRF data: loading with that background gives the
images back to within 1/255, and another background re-composites the scene.
"""

import argparse
import dataclasses
import json
import math
import os
import sys

import imageio.v3 as iio
import numpy as np

from nerf_jax.data import masks as masks_lib, multicam, scenes
from nerf_jax.data.dataset import DataError
from nerf_jax.data.llff import export_llff
from nerf_jax.data.scenes.scene import CAPTURE


def export_npz(dataset, path, rgb_only=False):
  """tiny_nerf arrays (images, poses, focal) plus near, far, background, pixel_center and any
  ground-truth depths, accs; with rgb_only, just the three arrays of the reference's
  tiny_nerf_data.npz (a loader then knows nothing of opacity, background or pixel centres, as
  with captured RGB images, and reads it through pixel corners as the reference does)."""
  arrays = {"images": dataset.images, "poses": dataset.poses, "focal": dataset.pinhole_focal()}
  if not rgb_only:
    arrays.update(near=dataset.near, far=dataset.far, background=np.asarray(dataset.background),
                  pixel_center=dataset.pixel_center,
                  **{k: getattr(dataset, k) for k in ("depths", "accs", "masks")
                     if getattr(dataset, k) is not None})
  np.savez(path, **arrays)


def _rgba8(images, accs, background):
  """uint8 [N, H, W, 4] PNG pixels from float32 images [N, H, W, 3] (see the module docstring)."""
  if background is None or accs is None:
    alpha = np.ones_like(images[..., :1])
    colour = images
  else:
    alpha = np.round(accs[..., None] * 255.0) / 255.0  # unpremultiply by the stored alpha
    emitted = images - (1.0 - alpha) * np.asarray(background, np.float32)
    colour = np.where(alpha > 0.0, emitted / np.maximum(alpha, 1e-12), 0.0)
  rgba = np.concatenate([np.clip(colour, 0.0, 1.0), alpha], -1)
  return np.round(rgba * 255.0).astype(np.uint8)


def export_blender(dataset, dirpath, split_at=None, background=None):
  """transforms_{train,val,test}.json and PNGs; train = views[:split_at], test = val = the rest.

  split_at: int or None (= the 80/20 split of `Dataset.split(-1)`).
  background: RGB triple or None; see the module docstring.
  """
  angle = 2.0 * math.atan(0.5 * dataset.width / dataset.pinhole_focal())
  parts = dict(zip(("train", "test"), dataset.split(-1 if split_at is None else split_at)))
  for split, part in parts.items():
    os.makedirs(os.path.join(dirpath, split), exist_ok=True)
    frames = []
    for k, rgba in enumerate(_rgba8(part.images, part.accs, background)):
      iio.imwrite(os.path.join(dirpath, split, f"r_{k}.png"), rgba)
      frames.append({"file_path": f"./{split}/r_{k}",
                     "transform_matrix": part.poses[k].astype(np.float64).tolist()})
      if part.masks is not None:
        frames[-1]["mask_path"] = f"./{split}/r_{k}_mask.png"
        masks_lib.write(os.path.join(dirpath, split, f"r_{k}_mask.png"), part.mask(k))
    meta = {"camera_angle_x": angle, "near": dataset.near, "far": dataset.far, "frames": frames}
    for name in (split, "val") if split == "test" else (split,):
      with open(os.path.join(dirpath, f"transforms_{name}.json"), "w") as f:
        json.dump(meta, f, indent=1)


def export_multiscale(dataset, dirpath, split_at=None):
  """mip-NeRF's multiscale folder (data/multicam.py) of `dataset`, every view through its own
  camera (a centred pinhole with fx = fy, else DataError); train = views[:split_at], test = val
  = the rest (split_at None: the 80/20 split); opaque PNGs of the composited images; lossmult
  and label from the data (1 and 0 without them)."""
  parts = dict(zip(("train", "test"), dataset.split(-1 if split_at is None else split_at)))
  splits = {}
  for split, part in parts.items():
    entries = []
    for k in range(len(part)):
      height, width, (fx, fy, cx, cy) = part.cameras.camera(k)
      if fx != fy or cx != 0.5 * width or cy != 0.5 * height:
        raise DataError(f"{dataset.name}: image {k} of {split} has intrinsics {(fx, fy, cx, cy)}: "
                        "the multiscale format stores centred pinholes with one focal length")
      image = part.image(k)
      entries.append({"rgba": np.concatenate([image, np.ones_like(image[..., :1])], -1),
                      "cam2world": part.poses[k], "focal": fx, "near": dataset.near,
                      "far": dataset.far,
                      "label": 0 if part.labels is None else part.labels[k],
                      "lossmult": 1.0 if part.lossmult is None else part.lossmult[k]})
    splits[split] = entries
  multicam.write(dirpath, {**splits, "val": splits["test"]})


def photographed(dataset, effects):
  """`dataset` (a built-in scene's views) with the capture `effects` applied to its 80%
  training views, in view order (module docstring); `dataset` itself without capture effects."""
  if not effects.names() & CAPTURE:
    return dataset
  train, test = dataset.split()
  train = scenes.photographed(train, effects)
  join = lambda a, b: None if a is None or b is None else np.concatenate([a, b])
  return dataclasses.replace(dataset, images=join(train.images, test.images),
                             poses=join(train.poses, test.poses),
                             depths=join(train.depths, test.depths),
                             accs=join(train.accs, test.accs), masks=join(train.masks, test.masks))


def main(argv=None):
  parser = argparse.ArgumentParser(description="Export a built-in scene.")
  parser.add_argument("--scene", required=True, help=f"one of {', '.join(scenes.SCENES)}")
  parser.add_argument("--format", required=True,
                      choices=("npz", "blender", "llff", "multiscale"))
  parser.add_argument("--out", required=True, help=".npz file, or Blender or LLFF folder to write")
  parser.add_argument("--num_views", type=int, default=100)
  parser.add_argument("--image_size", type=int, default=None,
                      help="height = width in pixels (default: the scene's, 100 or 400)")
  parser.add_argument("--pixel_center", type=float, default=0.5,
                      help="0.5: rays through pixel centres (what Blender and LLFF data assume)")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--alpha", action="store_true", help="Blender: alpha = opacity")
  parser.add_argument("--rgb_only", action="store_true",
                      help="npz: only images, poses, focal (no opacity, bounds or background)")
  args = parser.parse_args(argv)
  try:
    dataset = scenes.make_dataset(
        args.scene, args.num_views, args.image_size, args.image_size,
        pixel_center=args.pixel_center, seed=args.seed)  # focal: tiny_nerf's field of view
    dataset = photographed(dataset, scenes.get_scene(args.scene).effects)
    if args.format == "npz":
      export_npz(dataset, args.out, rgb_only=args.rgb_only)
    elif args.format == "llff":
      export_llff(dataset, args.out)
    elif args.format == "multiscale":
      export_multiscale(dataset, args.out)
    else:
      export_blender(dataset, args.out, background=dataset.background if args.alpha else None)
  except (ValueError, OSError) as e:  # DataError is a ValueError
    print(f"error: {e}", file=sys.stderr)
    return 1
  print(f"wrote {len(dataset)} views of {args.scene} to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
