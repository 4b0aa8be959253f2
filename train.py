"""Train a NeRF and render its results.

  python train.py                                   # configs/default.py on the built-in scene
  python train.py --config=configs/default.py --workdir=runs/a --config.num_samples=64
"""

from absl import app, flags
from ml_collections import config_flags

from nerf_jax import cli

_CONFIG = config_flags.DEFINE_config_file("config", "configs/default.py", "Training config.",
                                          lock_config=True)
_WORKDIR = flags.DEFINE_string("workdir", "", "Run directory (default: runs/<config>_<scene>).")


def main(argv):
  del argv
  cli.run_main(lambda: cli.train(_CONFIG.value, _WORKDIR.value, flags.FLAGS["config"].value))


if __name__ == "__main__":
  app.run(main)
