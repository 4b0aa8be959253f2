"""The numbers of each shipped config, as one hash each: a refactor that changes none of them
changes no behaviour (the same seeds give bit-identical parameters and images).

  python -m nerf_jax.bench.fingerprint                 # every shipped config, a line each
  python -m nerf_jax.bench.fingerprint fast llff       # some of them
  python -m nerf_jax.bench.fingerprint --help          # this text

Each config trains a few steps on a shrunken built-in scene (the configs that need a folder get
the built-in scene of their kind), then renders one test view. A line is the config's name, the
sha256 of every parameter and buffer and of the rendered view, and the view's PSNR. Compare two
runs on one machine and one jax version (other versions may round differently).
"""

import hashlib
import sys
import tempfile

import jax
import numpy as np

from nerf_jax.run import config_lib, experiment, train_lib

# The built-in scene each config trains on here (configs that read a folder get one of its kind).
SCENES = {"llff": "forward", "capture": "garden", "detail": "detail", "auto": "garden"}
SHRINK = {"data.num_views": 6, "data.image_size": 16, "data.holdout_from": 5,
          "train.max_steps": 6, "train.max_seconds": 0.0, "train.batch_rays": 128,
          "train.log_every": 6, "train.eval_every": 0, "train.checkpoint_every": 6,
          "render.after_training": False, "render.video_frames": 0}


def shrunk_config(name):
  """configs/<name>.py, on a small built-in scene, for a few steps."""
  config = config_lib.load(name)
  fields = dict(SHRINK)
  if name in SCENES:
    fields["data.path"] = ""
    fields["data.scene"] = SCENES[name]
  for field, value in fields.items():
    if not config_lib.unknown_override(config, field):
      config_lib.set_field(config, field, value)
  return config


def fingerprint(name):
  """(sha256 hex of the trained variables and one rendered test view, that view's PSNR)."""
  with tempfile.TemporaryDirectory() as workdir:
    result = train_lib.train_and_evaluate(shrunk_config(name), workdir)
    state = experiment.restore(workdir)[1]
  digest = hashlib.sha256()
  for leaf in jax.tree_util.tree_leaves(state.variables):
    digest.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
  # The rendered test views, through their scores; sorted, so the order of a view's keys is not
  # a difference.
  digest.update(repr([sorted(view.items()) for view in result["per_view"]]).encode())
  return digest.hexdigest()[:16], float(result["psnr"])


def main(argv):
  if any(arg in ("-h", "--help") for arg in argv[1:]):
    print(__doc__.strip())
    return 0
  names = argv[1:] or config_lib.available()
  for name in names:
    try:
      config_lib.resolve(name)
    except config_lib.ConfigError as e:
      print(f"error: {e}", file=sys.stderr)
      return 1
  for name in names:
    digest, psnr = fingerprint(name)
    print(f"{name:18s} {digest} {psnr:.4f}", flush=True)


if __name__ == "__main__":
  sys.exit(main(sys.argv))
