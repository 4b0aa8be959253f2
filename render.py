"""Render a trained NeRF from its workdir's latest checkpoint.

  python render.py --workdir=runs/a --mode=eval     # test views + metrics.json
  python render.py --workdir=runs/a --mode=video    # 360° orbit: rgb.mp4, depth.mp4
  python render.py --workdir=runs/a --mode=views --poses=poses.npy
"""

from absl import app, flags

from nerf_jax import cli

_WORKDIR = flags.DEFINE_string("workdir", None, "Training run directory.", required=True)
_MODE = flags.DEFINE_enum("mode", "eval", ["eval", "video", "views"], "What to render.")
_POSES = flags.DEFINE_string("poses", "", "views mode: .npy [N,4,4] or transforms-style .json.")
_OUT = flags.DEFINE_string("out", "", "Output directory (default: <workdir>/<mode>).")


def main(argv):
  del argv
  cli.run_main(lambda: cli.render(_WORKDIR.value, _MODE.value, _POSES.value, _OUT.value))


if __name__ == "__main__":
  app.run(main)
