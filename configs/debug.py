"""A seconds-long config for tests: tiny images, a small MLP, few samples and steps.

  python train.py --config=configs/debug.py --workdir=/tmp/debug
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.num_samples = 16  # few samples
  config.pos_encode_dims = 4  # few bands
  config.dir_encode_dims = 2  # few direction bands
  config.data.num_views = 12  # 12 views
  config.data.image_size = 24  # of 24×24 pixels
  config.data.holdout_from = 10  # views 10 and 11 are the test views
  config.model.depth = 3  # 3 layers
  config.model.width = 32  # of 32 units
  config.model.skip_layers = (1,)  # skip after the second layer
  config.model.view_width = 16  # narrow view layer
  config.train.default_steps = 20  # a few steps
  config.train.batch_rays = 256  # small batches
  config.train.warmup_steps = 0  # no warm-up
  config.train.log_every = 10  # log twice
  config.train.checkpoint_every = 10  # checkpoint twice
  config.render.chunk = 512  # small render chunks
  config.render.video_frames = 4  # a 4-frame video
  return config
