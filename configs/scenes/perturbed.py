"""`perturbed`: the `diffuse` objects with every training camera's pose off by 1° and 2% of the
scene's size (nerf_jax/data/scenes/photos.py), as structure from motion may leave them. Each
training camera gets a learnt SE(3) correction (train.pose_refinement); test views are rendered from
their true poses moved by the similarity that takes the given training cameras to the refined ones
(docs/appearance_and_poses.md).

  python train.py --config=configs/scenes/perturbed.py --workdir=runs/perturbed
"""

from nerf_jax.configs import fast


def get_config():
  config = fast.get_config()
  config.data.scene = "perturbed"  # the built-in capture with known pose errors
  config.train.pose_refinement = True  # learn a correction of each training camera
  return config
