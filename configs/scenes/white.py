"""`white`: Lambertian objects on a white background, like the NeRF-synthetic data. The renderer
composites on white, so empty space stays empty instead of the network painting white fog.

  python train.py --config=configs/scenes/white.py --workdir=runs/white
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.data.scene = "white"  # the built-in scene on a white background
  config.data.background = "white"  # composite on white, as the data were
  config.model.view_dependent = False  # Lambertian
  config.num_fine_samples = 0  # opaque surfaces
  return config
