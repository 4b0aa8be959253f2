"""mip-NeRF's setup (Barron et al. 2021) on the defaults: each pixel a cone, each sample interval
its frustum's Gaussian through the integrated positional encoding, one MLP for the coarse and
the fine pass. The rays carry their pixels' radii (cameras/cones.py).

  python train.py --config=configs/mipnerf.py --workdir=runs/mipnerf
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.model.encoding = "ipe"  # integrated positional encoding of the frustums' Gaussians
  config.pos_encode_dims = 16  # mip-NeRF's bands (max_deg_point 16): the fine ones fade with size
  config.num_samples = 64  # coarse samples per ray
  config.num_fine_samples = 64  # resampled from the coarse weights, as mip-NeRF's second pass
  config.model.shared_fine = True  # one MLP queried by both passes (mip-NeRF's single network)
  config.model.view_dependent = True  # colour takes the encoded viewing direction
  config.model.density_activation = "softplus"  # mip-NeRF's: smooth, no dead density
  return config
