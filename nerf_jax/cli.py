"""What train.py and render.py do, importable and testable.

Errors the user can fix (bad data, bad config, incompatible checkpoint, diverged training) are
printed as one line and exit with status 1; `--verbosity=1` (absl) shows the full traceback.
"""

import json
import os
import sys

from absl import flags, logging

from nerf_jax import checkpoints, render_lib, renderer, train_lib
from nerf_jax.data import loaders
from nerf_jax.model import make_model

# Exceptions whose message is the whole story for the user.
USER_ERRORS = (loaders.DataError, checkpoints.CheckpointError, train_lib.TrainingError,
               FileNotFoundError, ValueError)


def run_main(fn):
  """Run fn(); turn user errors into one line on stderr and exit status 1."""
  if not flags.FLAGS["verbosity"].present:
    logging.set_verbosity(logging.WARNING)  # hide JAX's backend-probing INFO lines by default
  try:
    fn()
  except KeyboardInterrupt as e:
    print(f"interrupted: {e}" if str(e) else "interrupted", file=sys.stderr)
    sys.exit(130)
  except USER_ERRORS as e:
    if logging.get_verbosity() >= logging.DEBUG:
      raise
    print(f"error: {e}", file=sys.stderr)
    sys.exit(1)


def default_workdir(config, config_path):
  name = os.path.splitext(os.path.basename(config_path or "default"))[0]
  data = os.path.basename(config.data.path.rstrip("/")) if config.data.path else config.data.scene
  return os.path.join("runs", f"{name}_{data}")


def train(config, workdir, config_path=""):
  workdir = workdir or default_workdir(config, config_path)
  print(f"workdir: {workdir}", flush=True)
  return train_lib.train_and_evaluate(config, workdir)


def restore_for_render(workdir):
  """(config, model, params, train_ds, test_ds, near, far) from a training workdir."""
  config = train_lib.load_config_json(workdir)
  path = checkpoints.latest_path(workdir)
  if path is None:
    raise train_lib.TrainingError(f"no checkpoint in {checkpoints.checkpoint_dir(workdir)}: "
                                  "train first (python train.py --workdir=...)")
  model = make_model(config.model)
  tx = train_lib.make_optimizer(config.train)
  state = train_lib.init_state(model, tx, config)
  state = checkpoints.restore(path, state, train_lib.model_signature(config))
  train_ds, test_ds = loaders.load_dataset(config.data)
  near, far = train_lib.bounds(config, train_ds)
  print(f"restored {path} (step {int(state.step)})", flush=True)
  return config, model, state.params, train_ds, test_ds, near, far


def render(workdir, mode, poses_path="", out_dir=""):
  config, model, params, train_ds, test_ds, near, far = restore_for_render(workdir)
  out_dir = out_dir or os.path.join(workdir, mode)
  if mode == "eval":
    result = render_lib.make_evaluator(model, config, near, far, test_ds)(params, out_dir=out_dir)
    print(f"test PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.4f} "
          f"over {len(result['per_view'])} views -> {out_dir}")
  elif mode == "video":
    paths = render_lib.render_video(model, params, config, near, far, train_ds, out_dir)
    print(f"wrote {paths['rgb']} and {paths['depth']}")
  else:
    if not poses_path:
      raise ValueError("--mode=views needs --poses=FILE (.npy [N,4,4] or .json with frames)")
    if not os.path.exists(poses_path):
      raise FileNotFoundError(f"{poses_path}: no such poses file")
    count = render_lib.render_views(model, params, config, near, far, train_ds,
                                    render_lib.load_poses(poses_path), out_dir)
    print(f"wrote {count} views to {out_dir}")
