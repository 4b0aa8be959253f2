"""The Keras reference's hyperparameters, exactly, to reproduce and compare against it.

NUM_SAMPLES=32, POS_ENCODE_DIMS=16, an 8×64 ReLU MLP with the input re-injected after layer 4,
position-only colour, 5 whole images per step, Adam at its default learning rate (1e-3, constant),
20 epochs over the training images (each a shuffle of them, remainder dropped), the 80/20 split,
near 2 / far 6, rays through pixel corners.

  python train.py --config=configs/keras_seed.py --workdir=runs/keras_seed
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.num_samples = 32  # NUM_SAMPLES
  config.pos_encode_dims = 16  # POS_ENCODE_DIMS
  config.data.holdout_from = -1  # 80/20 split
  config.data.pixel_center = 0.0  # rays through pixel corners, as the reference
  config.data.near = 2.0  # near plane, whatever the dataset says
  config.data.far = 6.0  # far plane
  config.model.depth = 8  # 8 Dense layers
  config.model.width = 64  # of 64 units
  config.model.skip_layers = (4,)  # input concatenated after the 5th layer (i % 4 == 0, i > 0)
  config.model.view_dependent = False  # the reference feeds positions only
  config.model.density_activation = "relu"  # sigma = relu(raw)
  config.train.batching = "images"  # whole images per step
  config.train.images_per_step = 5  # BATCH_SIZE = 5
  config.train.image_order = "epochs"  # each epoch visits every training image once
  config.train.lr = 1e-3  # keras.optimizers.Adam() default
  config.train.lr_final = 1e-3  # constant learning rate
  config.train.warmup_steps = 0  # no warm-up
  config.train.remat_chunk = 0  # the reference's plain step
  # 20 epochs of floor(80 / 5) = 16 steps each over the 80 training views of a 100-view scene.
  config.train.default_steps = 20 * 16  # EPOCHS = 20
  config.train.log_every = 16  # once per epoch
  config.train.checkpoint_every = 80  # every 5 epochs
  config.render.chunk = 8192  # bigger chunks: 50k rays per training step anyway
  config.render.video_frames = 120  # the reference renders 120 orbit frames
  return config
