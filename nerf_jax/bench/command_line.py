"""How a benchmark command runs, with train.py's conventions: absl flags, one --config flag (a
path or a name under configs/) with typed --config.FIELD=VALUE overrides, and errors the user
can fix printed as one line with exit status 1 (nerf_jax.cli); and the config a command trains
(`command_config`: the command's fields set, auto keeps them).

Each command is `define_*_flags(flag_values, argv)` and a function of the parsed flag values, so
tests parse and run it on a private FlagValues; its `*_main` runs it here under absl's app.run:
  python -m nerf_jax.bench          cli.py: the sweeps
  python -m nerf_jax.bench.render   render.py: render speed and memory of a trained model
  python -m nerf_jax.bench.profile  profile.py: where a train step's time goes
"""

import sys

import ml_collections
from absl import app, flags
from ml_collections import config_flags

from nerf_jax import cli
from nerf_jax.backend import errors
from nerf_jax.run import config_lib


def define_config(values, argv, help_text):
  """The --config flag (default configs/default.py) on the FlagValues `values`. argv: the command
  line after cli.resolve_config_argv, where the flag finds its --config.FIELD overrides."""
  config_flags.DEFINE_config_file("config", config_lib.resolve("default"), help_text,
                                  flag_values=values, lock_config=True, sys_argv=argv)


def run_command(define, command, argv, with_config):
  """Parse `argv` (default sys.argv) into the global flags defined by `define` and run
  command(flags.FLAGS, config spec, argv as given) under cli.run_main; exit status 0."""
  given = list(sys.argv if argv is None else argv)
  argv, spec = cli.resolve_config_argv(given) if with_config else (given, "")
  before = set(flags.FLAGS)
  define(flags.FLAGS, argv)
  for name in sorted(set(flags.FLAGS) - before):  # --help lists them as the command's own flags
    flags.FLAGS.register_key_flag_for_module(sys.argv[0], flags.FLAGS[name])

  def run(_):
    cli.run_main(lambda: command(flags.FLAGS, spec, given))  # app.run exits with what run returns

  app.run(run, argv=argv, flags_parser=errors.parse_flags)


def command_config(base, fields, overrides=()):
  """(a copy of the ConfigDict `base` with `fields` ({dotted field: value}) set, {field: value}
  of what the command set: `overrides` (the dotted fields the command line set on `base`), then
  `fields`). These go into config.auto_flags after those `base` holds: auto keeps them."""
  config = ml_collections.ConfigDict(base.to_dict())
  for name, value in fields.items():
    config_lib.set_field(config, name, value)
  names = tuple(dict.fromkeys((*overrides, *fields)))
  config.auto_flags = tuple(dict.fromkeys((*config.auto_flags, *names)))
  return config, {name: config_lib.get_field(config, name) for name in names}
