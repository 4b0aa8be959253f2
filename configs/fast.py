"""The fast setup: multiresolution dense feature grids + a one-layer MLP, sampling only the scene
box. Reaches in seconds what the MLP reaches in minutes on a CPU (see the README's performance
section for measured figures).

  python train.py --config=configs/fast.py --workdir=runs/fast
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.num_samples = 64  # samples inside the scene box (denser than 64 over [near, far])
  config.data.scene_bound = 1.5  # half-size of the box holding the scene: sample only inside it
  config.model.encoding = "grid"  # dense multiresolution grids instead of positional encoding
  config.model.grid.resolutions = (32, 64, 128)  # lattice points per side of each grid
  config.model.grid.features = 4  # features per lattice point
  config.model.grid_bound = 1.5  # the grids cover [-1.5, 1.5]^3
  config.model.width = 64  # the hidden layer over the grid features
  config.model.density_activation = "softplus"  # smooth and never dead, unlike relu on a grid
  config.train.batch_rays = 2048  # rays per step
  config.train.lr = 1e-2  # grids want a larger step than MLPs
  config.train.lr_final = 5e-4  # decayed to this at max_steps
  config.train.warmup_steps = 20  # short warm-up
  config.train.remat_chunk = 0  # the grid model's step is not MLP-bound
  config.train.random_background = True  # RGBA data: no floaters (docs/detail_scene.md)
  config.train.default_steps = 1500  # step budget without max_steps or max_seconds
  config.train.checkpoint_every = 500  # steps between checkpoints
  config.render.chunk = 2048  # rays per render call: marching's arrays stay in cache
  config.render.video_frames = 120  # the full 120-frame orbit
  return config
