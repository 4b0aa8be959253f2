"""`detail`: NeRF-synthetic-like data — 400 x 400 views of finely textured objects, thin rods
(~1-2 px wide), glossy spheres and a transparent (black, alpha = acc) background. Anti-aliased
ground truth (3 x 3 rays per pixel), rendered once and cached (see nerf_jax/data/scenes/cache.py).

Trained with configs/detail.py (dense grids, view branch, occupancy-placed samples, density
levels with a colour budget, random backgrounds while training), chosen by measurement on this
scene against the hash grid, the MLP, fast.py's 64 box samples (docs/detail_scene.md) and the
MLP's density (docs/quality_per_second.md).

  python train.py --config=configs/scenes/detail.py --workdir=runs/detail
  python -m nerf_jax.data.export --scene=detail --format=blender --alpha --out=/tmp/detail
"""

from nerf_jax.configs import detail


def get_config():
  config = detail.get_config()
  config.data.scene = "detail"  # the built-in textured scene with thin rods
  config.data.image_size = 400  # NeRF-synthetic-like resolution (the scene's default)
  config.data.background = "black"  # the scene's background (alpha = acc over it)
  return config
