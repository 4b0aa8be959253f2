"""`fog`: a semi-transparent medium with objects inside and behind it. Light is absorbed all
along the ray, so the weights are spread out and then spike at the surfaces behind the fog:
hierarchical sampling puts the fine samples where the coarse weights are. Lambertian shading, so
no view branch.

  python train.py --config=configs/scenes/fog.py --workdir=runs/fog
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.data.scene = "fog"  # the built-in scene with a homogeneous medium
  config.data.background = "black"  # the scene's background
  config.model.view_dependent = False  # the medium and the surfaces are Lambertian
  config.num_samples = 32  # coarse samples ...
  config.num_fine_samples = 32  # ... plus fine samples where the coarse weights are
  config.model.shared_fine = True  # one network for both passes: half the parameters
  return config
