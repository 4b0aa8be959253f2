"""`glossy`: Blinn-Phong highlights that move with the viewer. A position-only model can only
average them away, so the view branch (the paper's 5D input) is switched on; surfaces are opaque,
so there is no fine pass.

  python train.py --config=configs/scenes/glossy.py --workdir=runs/glossy
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.data.scene = "glossy"  # the built-in scene with specular highlights
  config.data.background = "black"  # the scene's background
  config.model.view_dependent = True  # highlights depend on the viewing direction
  config.dir_encode_dims = 4  # the paper's 4 bands for directions
  config.num_fine_samples = 0  # opaque surfaces: no hierarchical sampling needed
  return config
