"""The original tiny NeRF notebook's setup: 6 frequencies, an 8×256 MLP, 64 samples, one image
per step at learning rate 5e-4, position-only colour, no hierarchical sampling.

  python train.py --config=configs/tiny_nerf.py --workdir=runs/tiny_nerf
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.num_samples = 64  # N_samples
  config.pos_encode_dims = 6  # L_embed
  config.model.depth = 8  # 8 layers
  config.model.width = 256  # of 256 units
  config.model.skip_layers = (4,)  # input re-injected after layer 5 (i % 4 == 0, i > 0)
  config.model.view_dependent = False  # position-only
  config.data.pixel_center = 0.0  # rays through pixel corners, as the notebook
  config.train.batching = "images"  # one whole image per step
  config.train.images_per_step = 1  # one image
  config.train.lr = 5e-4  # Adam(5e-4)
  config.train.lr_final = 5e-4  # constant
  config.train.warmup_steps = 0  # no warm-up
  config.train.default_steps = 1000  # N_iters
  config.train.remat_chunk = 0  # the notebook's plain step
  config.train.log_every = 25  # i_plot
  return config
