"""The 8×64 MLP at 64 samples and 1024 rays per step (the default until the speed work): the
base of the README's knob, effects, precision, remat and scaling sweeps.

  python -m nerf_jax.bench --sweep=samples,freqs,width --config=mlp64 --budget_seconds=60
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.num_samples = 64  # stratified samples per ray
  config.train.batch_rays = 1024  # rays per step
  config.train.lr = 2e-3  # initial Adam learning rate
  config.train.remat_chunk = 0  # the plain step
  config.train.default_steps = 600  # step budget without max_steps or max_seconds (~4.5 min)
  config.train.checkpoint_every = 200  # steps between checkpoints
  return config
