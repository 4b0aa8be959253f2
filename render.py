"""Render a trained NeRF from its workdir's newest checkpoint (= `nerf-render`).

  python render.py --workdir=runs/a --mode=eval     # test views + metrics.json
  python render.py --workdir=runs/a --mode=video    # 360° orbit: rgb.mp4, depth.mp4
  python render.py --workdir=runs/a --mode=views --poses=poses.npy
  python render.py --workdir=runs/a --mode=mesh --resolution=256 --threshold=50
  python render.py --workdir=runs/a --mode=eval --config.eval.fit_steps=300  # over config.json
"""

from nerf_jax import cli

if __name__ == "__main__":
  cli.render_main()
