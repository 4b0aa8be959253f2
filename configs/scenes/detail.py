"""`detail`: NeRF-synthetic-like data — 400 x 400 views of finely textured objects, thin rods
(~1-2 px wide), glossy spheres and a transparent (black, alpha = acc) background. Anti-aliased
ground truth (3 x 3 rays per pixel), rendered once and cached (see nerf_jax/scenes/cache.py).
Highlights need the view branch; the rods and glyphs need more samples than the thick
primitives of the other scenes, so a fine pass puts samples where the coarse weights are.

  python train.py --config=configs/scenes/detail.py --workdir=runs/detail
  python -m nerf_jax.data.export --scene=detail --format=blender --alpha --out=/tmp/detail
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.data.scene = "detail"  # the built-in textured scene with thin rods
  config.data.image_size = 400  # NeRF-synthetic-like resolution (the scene's default)
  config.data.background = "black"  # the scene's background (alpha = acc over it)
  config.model.view_dependent = True  # the glossy spheres' highlights
  config.dir_encode_dims = 4  # the paper's 4 bands for directions
  config.num_samples = 64  # coarse samples: the plinth, crate and tower are thick ...
  config.num_fine_samples = 64  # ... but rods ~0.012 wide need samples where the weights are
  return config
