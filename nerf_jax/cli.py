"""What train.py and render.py do, importable and testable.

Errors the user can fix (bad flags or config overrides, bad data, incompatible checkpoint,
diverged training) are printed as one line and exit with status 1; `--verbosity=1` (absl) shows
the full traceback.
"""

import os
import sys

from absl import flags, logging
from ml_collections import config_dict

from nerf_jax import checkpoints, mesh, parallel, render_lib, train_lib
from nerf_jax.data import loaders
from nerf_jax.model import make_model

# Exceptions whose message is the whole story for the user.
USER_ERRORS = (loaders.DataError, checkpoints.CheckpointError, train_lib.TrainingError,
               FileNotFoundError, ValueError)


def _wants_traceback(argv):
  return any(a.lstrip("-").split("=")[0] in ("verbosity", "v") for a in argv[1:])


def parse_flags(argv, flag_values=flags.FLAGS):
  """`app.run`'s flags_parser: a bad flag, config file or override exits 1 with one line.

  Returns the positional arguments; refuses any (every setting is a flag).
  """
  try:
    rest = flag_values(argv)
    for name in flag_values:  # config_flags defers a failed config load to the first use
      value = flag_values[name].value
      if type(value).__name__ == "_ErrorConfig":
        if _wants_traceback(argv):
          value.get("seed")  # raises the deferred error
        _fail(_config_file_error(name, value._error, argv))  # pylint: disable=protected-access
  except Exception as e:  # absl and config_flags raise many types; all are the user's input
    flag_error_exit(e, argv)
  if len(rest) > 1:
    _fail(f"unexpected argument {rest[1]!r}: settings are flags, e.g. --config.data.path=...")
  return rest


def flag_error_exit(exc, argv):
  """Exit 1 with one line for an exception raised while defining or parsing flags (re-raise it
  if --verbosity is given). Call it from an `except` block."""
  if _wants_traceback(argv):
    raise exc
  _fail(_flag_error(exc, argv))


def _fail(message):
  print(f"error: {message}", file=sys.stderr)
  sys.exit(1)


def _config_file_error(name, exc, argv):
  """One line for a config file that could not be loaded."""
  prefix = (f"--{name}=", f"-{name}=")
  spec = next((a.split("=", 1)[1] for a in argv if a.startswith(prefix)), "")
  path = spec.split(":")[0]
  if path and not os.path.exists(path):
    return f"--{name}={spec}: no such config file"
  lines = [l.strip() for l in str(exc).splitlines() if l.strip()] or [type(exc).__name__]
  return f"--{name}={spec}: cannot load the config file ({type(exc).__name__}: {lines[-1]})"


def _flag_error(exc, argv):
  """One line naming the flag and what is wrong with it."""
  unknown = _unknown_field(exc)
  if unknown:
    return unknown
  spec = next((a.split("=", 1)[1] for a in argv if a.startswith(("--config=", "-config="))), "")
  if spec and _raised_in(exc, spec.split(":")[0]):
    return _config_file_error("config", exc, argv)
  lines = [l.strip() for l in str(exc).splitlines() if l.strip()]
  if not lines:
    return type(exc).__name__
  # A config file that raised: absl quotes its traceback; its last line says what happened.
  return lines[0] if len(lines) == 1 else f"{lines[0]} {lines[-1]}"


def _raised_in(exc, path):
  """Whether `exc` was raised by the code (or the syntax) of the file at `path`."""
  path = os.path.abspath(path)
  if isinstance(exc, SyntaxError) and exc.filename:
    return os.path.abspath(exc.filename) == path
  tb = exc.__traceback__
  while tb is not None:
    if os.path.abspath(tb.tb_frame.f_code.co_filename) == path:
      return True
    tb = tb.tb_next
  return False


def _unknown_field(exc):
  """For an override of a field the config lacks: '--config.a.b: config.a has no field ...'."""
  tb, field, config = exc.__traceback__, None, None
  while tb is not None:  # config_flags' parser frame holds the override being parsed
    frame = tb.tb_frame.f_locals
    if isinstance(frame.get("field_path"), str) and isinstance(frame.get("config"),
                                                              config_dict.ConfigDict):
      field, config = frame["field_path"], frame["config"]
    tb = tb.tb_next
  if field is None:
    return None
  node, parts, known = config, field.split("."), ["config"]
  for part in parts:
    if not isinstance(node, config_dict.ConfigDict) or part not in node:
      valid = f" (fields: {', '.join(sorted(node.keys()))})" if isinstance(
          node, config_dict.ConfigDict) else ""
      return f"--config.{field}: {'.'.join(known)} has no field {part!r}{valid}"
    node, known = node[part], known + [part]
  return None


def find_config(path):
  """`path` if it exists, else for 'configs/NAME.py' the copy installed with the package (so
  the README's commands work from any directory after `pip install`)."""
  if os.path.exists(path) or not path.startswith("configs" + os.sep):
    return path
  try:
    import configs  # pylint: disable=import-outside-toplevel
  except ImportError:
    return path
  installed = os.path.join(os.path.dirname(configs.__file__), path[len("configs") + 1:])
  return installed if os.path.exists(installed) else path


def default_config_path():
  return find_config(os.path.join("configs", "default.py"))


def resolve_config_args(argv):
  """argv with `--config=configs/X.py[:args]` pointing at the installed copy when needed."""
  out = []
  for arg in argv:
    if arg.startswith("--config="):
      path, colon, rest = arg[len("--config="):].partition(":")
      arg = f"--config={find_config(path)}{colon}{rest}"
    out.append(arg)
  return out


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
  parallel.initialize_distributed()
  workdir = workdir or default_workdir(config, config_path)
  if parallel.is_main_process():
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
  state = checkpoints.restore(path, train_lib.state_template(model, tx, config),
                              train_lib.model_signature(config))
  train_ds, test_ds = loaders.load_dataset(config.data)
  near, far = train_lib.bounds(config, train_ds)
  print(f"restored {path} (step {int(state.step)})", flush=True)
  return config, model, state.params, train_ds, test_ds, near, far


def render(workdir, mode, poses_path="", out_dir="", depth_npy=False, resolution=128,
           threshold=50.0, bound=0.0, scale=1.0):
  """Render `mode` ('eval', 'video', 'views' or 'mesh') from the newest checkpoint of `workdir`.

  depth_npy: video mode also writes float depth_frames.npy. resolution, threshold, bound: mesh
  mode (see mesh.extract). scale: video and views modes render `scale` times the training
  images' pixels per side.
  """
  if not os.path.isdir(workdir):
    raise FileNotFoundError(f"--workdir={workdir}: no such directory")
  config, model, params, train_ds, test_ds, near, far = restore_for_render(workdir)
  out_dir = out_dir or os.path.join(workdir, mode)
  if scale <= 0:
    raise ValueError(f"--scale={scale}: must be positive")
  if mode == "mesh":
    surface = mesh.extract(model, params, config, resolution, threshold, bound)
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, "mesh.ply")
    mesh.write_ply(path, surface["vertices"], surface["faces"], surface["colors"])
    print(f"wrote {len(surface['vertices'])} vertices and {len(surface['faces'])} faces "
          f"to {path}")
    return path
  if mode == "eval":
    result = render_lib.make_evaluator(model, config, near, far, test_ds)(params, out_dir=out_dir)
    print(f"test PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.4f} "
          f"over {len(result['per_view'])} views -> {out_dir}")
  elif mode == "video":
    paths = render_lib.render_video(model, params, config, near, far, train_ds, out_dir,
                                    depth_npy=depth_npy, scale=scale)
    print(f"wrote {', '.join(paths.values())}")
  else:
    if not poses_path:
      raise ValueError("--mode=views needs --poses=FILE (.npy [N,4,4] or .json with frames)")
    if not os.path.exists(poses_path):
      raise FileNotFoundError(f"{poses_path}: no such poses file")
    count = render_lib.render_views(model, params, config, near, far, train_ds,
                                    render_lib.load_poses(poses_path), out_dir, scale)
    print(f"wrote {count} views to {out_dir}")
