"""`diffuse`: Lambertian objects on black. Colour does not depend on the viewing direction and
every surface is opaque, so the model needs neither the view branch nor a fine pass: this is the
default model, on its cheapest path.

  python train.py --config=configs/scenes/diffuse.py --workdir=runs/diffuse
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.data.scene = "diffuse"  # the built-in Lambertian scene
  config.data.background = "black"  # the scene's background
  config.model.view_dependent = False  # Lambertian: colour is the same from every direction
  config.num_fine_samples = 0  # opaque, thick objects: stratified samples find them
  return config
