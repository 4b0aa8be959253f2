"""Train a NeRF and render its results (= `nerf-train`; see nerf_jax/cli.py for the flags).

  python train.py                                   # configs/default.py on the built-in scene
  python train.py --config=configs/default.py --workdir=runs/a --config.num_samples=64
"""

from nerf_jax import cli

if __name__ == "__main__":
  cli.train_main()
