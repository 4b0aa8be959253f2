"""`landmark_sfm`: the `landmark` photo collection (configs/scenes/landmark.py) with the training
poses a structure from motion forced to one shared focal gives
(nerf_jax/data/scenes/landmark_sfm.py): each photo's zoom and lens absorbed by its pose (a
zoomed-in photo's camera moved closer), as a real collection posed with one camera stores them.
The same config as landmark's; only the poses differ (docs/photo_collections.md, "The SfM
twin").

  python train.py --config=configs/scenes/landmark_sfm.py --workdir=runs/landmark_sfm
"""

from nerf_jax.configs.scenes import landmark


def get_config():
  config = landmark.get_config()
  config.data.scene = "landmark_sfm"  # landmark's photos, posed by a one-focal reconstruction
  return config
