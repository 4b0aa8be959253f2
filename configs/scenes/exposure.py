"""`exposure`: the `diffuse` objects photographed with a per-photo exposure (±0.6 stops) and white
balance (±15% per channel) on the training views (nerf_jax/data/scenes/photos.py); the held-out
views keep the neutral look. Per-photo appearance codes (GLO) let the field keep one colour per
point while each photo keeps its own look; test views are rendered with the mean code
(docs/appearance_and_poses.md).

  python train.py --config=configs/scenes/exposure.py --workdir=runs/exposure
"""

from nerf_jax.configs import fast


def get_config():
  config = fast.get_config()
  config.data.scene = "exposure"  # the built-in capture with per-photo exposure
  config.model.appearance_dims = 8  # a code of 8 numbers per training photo
  return config
