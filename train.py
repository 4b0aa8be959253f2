"""Train a NeRF and render its results (the same as `python -m nerf_jax.train`, `nerf-train`).

  python train.py                                   # configs/default.py on the built-in scene
  python train.py --config=configs/default.py --workdir=runs/a --config.num_samples=64
"""

from nerf_jax import train

if __name__ == "__main__":
  train.main()
