"""The transient head's measurement (docs/transient_head.md): the built-in `diffuse` scene with
random opaque rectangles of random flat colours painted into a share of its training photos
(the test views stay clean), trained for a wall-clock budget with and without
config.model.transient, the static field scored on the clean test views.

  nice -n 19 taskset -c 1 python docs/bench/transient/occluders.py --dims=0 --seconds=270 \
      --workdir=/tmp/occ_off
  nice -n 19 taskset -c 1 python docs/bench/transient/occluders.py --dims=16 --seconds=270 \
      --workdir=/tmp/occ_on

Prints one JSON line (and appends it to --out): the settings, steps and test PSNR.
"""

import argparse
import json

import numpy as np

from nerf_jax.data import loaders
from nerf_jax.run import config_lib, train_lib


def paint_occluders(ds, share, seed):
  """Paint 1-3 opaque rectangles, each 1/6 to 2/5 of the image side and of one random colour,
  into round(share · N) of `ds`'s images (in place; their opacity, where the data has it, made
  1 there). Returns the painted images' indices."""
  rng = np.random.default_rng(seed)
  count = len(ds.images)
  chosen = sorted(rng.choice(count, int(round(share * count)), replace=False).tolist())
  for i in chosen:
    height, width = ds.images[i].shape[:2]
    for _ in range(rng.integers(1, 4)):
      h = rng.integers(height // 6, int(height / 2.5))
      w = rng.integers(width // 6, int(width / 2.5))
      y, x = rng.integers(0, height - h), rng.integers(0, width - w)
      ds.images[i][y:y + h, x:x + w] = rng.uniform(0.0, 1.0, 3)
      if ds.accs is not None:
        ds.accs[i][y:y + h, x:x + w] = 1.0
  return chosen


def main():
  parser = argparse.ArgumentParser()
  parser.add_argument("--config", default="default")
  parser.add_argument("--dims", type=int, default=0, help="config.model.transient.dims")
  parser.add_argument("--seconds", type=float, default=270.0, help="config.train.max_seconds")
  parser.add_argument("--share", type=float, default=0.6, help="share of photos occluded")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--workdir", required=True)
  parser.add_argument("--out", default="")
  args = parser.parse_args()
  config = config_lib.load(args.config)
  config.render.after_training = False
  config.model.transient.dims = args.dims
  config.train.max_seconds = args.seconds
  load = loaders.load_dataset

  def load_with_occluders(settings):
    train, test = load(settings)
    paint_occluders(train, args.share, args.seed)
    return train, test
  loaders.load_dataset = load_with_occluders
  result = train_lib.train_and_evaluate(config, args.workdir)
  record = {"config": args.config, "dims": args.dims, "seconds": args.seconds,
            "share": args.share, "steps": result["steps"], "psnr": round(result["psnr"], 2),
            "ssim": round(result.get("ssim", float("nan")), 4)}
  print(json.dumps(record))
  if args.out:
    with open(args.out, "a") as f:
      f.write(json.dumps(record) + "\n")


if __name__ == "__main__":
  main()
