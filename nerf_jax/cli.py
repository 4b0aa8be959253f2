"""The command lines: `nerf-train` (= python train.py) and `nerf-render` (= python render.py).

  nerf-train                                          # configs/default.py on the built-in scene
  nerf-train --config=fast --workdir=runs/a           # a config by name, from any directory
  nerf-train --config=configs/debug.py --config.num_samples=64
  nerf-render --workdir=runs/a --mode=eval|video|views|mesh
  nerf-render --workdir=runs/a --mode=eval --config.eval.fit_steps=300   # over its config.json

Errors the user can fix (bad flags, config files or overrides, bad data, incompatible
checkpoint, diverged training) are printed as one line and exit with status 1; `--verbosity=1`
(absl) shows the full traceback instead.
"""

import os
import sys

from absl import app, flags
from ml_collections import config_flags

from nerf_jax.backend import determinism, errors
from nerf_jax.data import DataError
from nerf_jax.run import config_lib, experiment, outputs, train_lib
from nerf_jax.train import checkpoints, parallel
from nerf_jax.viewer import training as live_viewer

# Exceptions whose message is the whole story for the user.
USER_ERRORS = (DataError, checkpoints.CheckpointError, experiment.TrainingError,
               config_lib.ConfigError, FileNotFoundError, ValueError)


def _config_spec(argv):
  """The value of --config in argv ('' if absent)."""
  for i, arg in enumerate(argv[1:], 1):
    if arg.startswith(("--config=", "-config=")):
      return arg.split("=", 1)[1]
    if arg in ("--config", "-config") and i + 1 < len(argv):
      return argv[i + 1]
  return ""


def resolve_config_argv(argv):
  """argv with --config pointing at a file, after checking the config loads and every
  `--config.FIELD=` override names a field it has. Returns (argv, config spec as given);
  exits 1 with one line otherwise (raises with --verbosity)."""
  spec = _config_spec(argv) or "default"
  try:
    path = config_lib.resolve(spec)
    config = config_lib.load(spec)
  except config_lib.ConfigError as e:
    if errors.wants_traceback(argv):
      raise
    errors.fail(str(e))
  out = []
  for arg in argv:
    if arg.startswith("--config."):
      arg = _current_spelling(arg)
      problem = config_lib.unknown_override(config, arg[len("--config."):].split("=", 1)[0])
      if problem:
        errors.fail(problem)
    if not arg.startswith(("--config=", "-config=")):
      out.append(arg)
  return [out[0], f"--config={path}", *out[1:]], spec


def _current_spelling(arg):
  """A `--config.FIELD=VALUE` argument with a renamed FIELD spelled as it is now (one
  deprecation line; config_lib.RENAMED)."""
  field, equals, value = arg[len("--config."):].partition("=")
  if config_lib.renamed(field) == field:
    return arg
  print(config_lib.deprecation(field, config_lib.renamed(field)), flush=True)
  return f"--config.{config_lib.renamed(field)}{equals}{value}"


def run_main(fn):
  """Run fn() for its effects; turn user errors (USER_ERRORS) into one line on stderr and exit
  status 1 (backend/errors.run_main)."""
  errors.run_main(fn, USER_ERRORS)


def default_workdir(config, config_spec):
  """runs/<config name>_<scene or data folder>."""
  name = os.path.splitext(os.path.basename(config_spec.split(":")[0] or "default"))[0]
  data = os.path.basename(config.data.path.rstrip("/")) if config.data.path else config.data.scene
  return os.path.join("runs", f"{name}_{data}")


def override_names(argv):
  """The dotted fields of the `--config.FIELD=VALUE` arguments in argv."""
  return tuple(a[len("--config."):].split("=", 1)[0] for a in argv if a.startswith("--config."))


# What watches a nerf-train run: the live viewer (config.viewer.enabled), viewer/training.py.
TRAIN_WATCHERS = (live_viewer.start,)


def prepare(config, workdir, config_spec="", overrides=()):
  """The workdir a training run of `config` uses (`workdir`, default: `default_workdir`),
  announced; the processes joined (parallel.initialize_distributed). overrides: the fields set
  on the command line, which config.auto keeps as they are (config.auto_flags)."""
  if config.auto:
    config.auto_flags = tuple(overrides)
  if config.train.get("deterministic", False):
    determinism.require()  # before anything below starts jax's backends (is_main_process does)
  parallel.initialize_distributed()
  workdir = workdir or default_workdir(config, config_spec)
  if parallel.is_main_process():
    print(f"workdir: {workdir}", flush=True)
  return workdir


def train(config, workdir, config_spec="", overrides=()):
  """Train `config` into `workdir` as nerf-train does (`prepare`, then
  train_lib.train_and_evaluate with TRAIN_WATCHERS); returns the final metrics."""
  workdir = prepare(config, workdir, config_spec, overrides)
  return train_lib.train_and_evaluate(config, workdir, watchers=TRAIN_WATCHERS)


def train_main(argv=None):
  """`nerf-train` / train.py: the config flag with overrides, --workdir; train and render."""
  argv, spec = resolve_config_argv(list(sys.argv if argv is None else argv))
  config = config_flags.DEFINE_config_file("config", config_lib.resolve("default"),
                                           "Training config: a path or a name under configs/.",
                                           lock_config=True, sys_argv=argv)
  workdir = flags.DEFINE_string("workdir", "", "Run directory (default: runs/<config>_<scene>).")

  def main(_):
    with errors.one_line_errors(USER_ERRORS):  # no wrapper between here and the step's jit
      run_dir = prepare(config.value, workdir.value, spec, override_names(argv))
      train_lib.train_and_evaluate(config.value, run_dir, watchers=TRAIN_WATCHERS)

  app.run(main, argv=argv, flags_parser=errors.parse_flags)


def render_main(argv=None):
  """`nerf-render` / render.py: render a trained workdir's newest checkpoint, under the config
  the run saved; `--config.eval.FIELD=VALUE` overrides how the test views are scored (the
  evaluation settings, evaluation.Settings), and nothing else: the rest is what it trained with."""
  argv = list(sys.argv if argv is None else argv)
  for arg in argv[1:]:
    if arg.startswith(("--config", "-config")) and not arg.startswith("--config.eval."):
      errors.fail(f"{arg.split('=', 1)[0]}: render.py restores the run's config.json; only the "
                  "evaluation settings can be overridden (--config.eval.FIELD=VALUE)")
  config_flags.DEFINE_config_dict("config", config_lib.default(), "Evaluation settings over the "
                                  "run's config.json: --config.eval.FIELD=VALUE.",
                                  lock_config=True, sys_argv=argv)
  workdir = flags.DEFINE_string("workdir", None, "Training run directory.", required=True)
  mode = flags.DEFINE_enum("mode", "eval", list(outputs.MODES), "What to render.")
  poses = flags.DEFINE_string("poses", "", "views mode: .npy [N,4,4] or transforms-style .json; "
                              "path mode: the key cameras (the viewer's camera_path.json).")
  path_frames = flags.DEFINE_integer("path_frames", 30, "path mode: video frames from one key "
                                     "camera to the next (interpolated).")
  out = flags.DEFINE_string("out", "", "Output directory (default: <workdir>/<mode>).")
  depth_npy = flags.DEFINE_bool("depth_npy", False, "video mode: also save float32 depth of "
                                "every frame as depth_frames.npy [F, H, W] (scene units).")
  resolution = flags.DEFINE_integer("resolution", 128, "mesh mode: lattice points per side.")
  threshold = flags.DEFINE_float("threshold", 50.0, "mesh mode: density of the surface "
                                 "(1 / scene unit).")
  bound = flags.DEFINE_float("bound", 0.0, "mesh mode: half-size of the box [-b, b]^3 "
                             "(0 = config.data.scene_bound, else the grid's, else 1.5).")
  scale = flags.DEFINE_float("scale", 1.0, "video and views modes: pixels per side relative to "
                             "the training images (2 = twice as wide and tall, same view).")

  def run(_):
    run_main(lambda: outputs.render(workdir.value, mode.value, poses.value, out.value,
                                    depth_npy.value, resolution.value, threshold.value,
                                    bound.value, scale.value, path_frames.value,
                                    flags.FLAGS["config"].override_values))

  app.run(run, argv=argv, flags_parser=errors.parse_flags)
