"""Render a trained NeRF from its workdir: `python -m nerf_jax.render`, `nerf-render`, `render.py`.

  nerf-render --workdir=runs/a --mode=eval     # test views + metrics.json
  nerf-render --workdir=runs/a --mode=video    # 360° orbit: rgb.mp4, depth.mp4
  nerf-render --workdir=runs/a --mode=views --poses=poses.npy
  nerf-render --workdir=runs/a --mode=mesh --resolution=256 --threshold=50   # mesh.ply
"""

from absl import app, flags

from nerf_jax import cli


def main():
  """Define the flags, parse them (one-line errors) and render."""
  workdir = flags.DEFINE_string("workdir", None, "Training run directory.", required=True)
  mode = flags.DEFINE_enum("mode", "eval", ["eval", "video", "views", "mesh"], "What to render.")
  poses = flags.DEFINE_string("poses", "", "views mode: .npy [N,4,4] or transforms-style .json.")
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

  def run(argv):
    del argv
    cli.run_main(lambda: cli.render(workdir.value, mode.value, poses.value, out.value,
                                    depth_npy.value, resolution.value, threshold.value,
                                    bound.value, scale.value))

  app.run(run, flags_parser=cli.parse_flags)


if __name__ == "__main__":
  main()
