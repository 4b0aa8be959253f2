"""Train a NeRF and render its results: `python -m nerf_jax.train`, `nerf-train`, `train.py`.

  nerf-train                                        # configs/default.py on the built-in scene
  nerf-train --config=configs/debug.py --workdir=runs/a --config.num_samples=64
"""

import sys

from absl import app, flags
from ml_collections import config_flags

from nerf_jax import cli


def main():
  """Define the flags, parse them (one-line errors) and train."""
  sys.argv = cli.resolve_config_args(sys.argv)  # config_flags reads overrides from sys.argv
  try:  # without --config, the default config and its overrides are parsed right here
    config = config_flags.DEFINE_config_file("config", cli.default_config_path(),
                                             "Training config.", lock_config=True)
  except Exception as e:  # pylint: disable=broad-except
    cli.flag_error_exit(e, sys.argv)
  workdir = flags.DEFINE_string("workdir", "", "Run directory (default: runs/<config>_<scene>).")

  def run(argv):
    del argv
    config_path = config_flags.get_config_filename(flags.FLAGS["config"])
    cli.run_main(lambda: cli.train(config.value, workdir.value, config_path))

  app.run(run, argv=sys.argv, flags_parser=cli.parse_flags)


if __name__ == "__main__":
  main()
