"""`crowd`: the `exposure` capture (per-photo exposure and white balance on the training views)
with passers-by: in 60% of the training photos one to three opaque balls, boxes or people
stand between the camera and the subject (nerf_jax/data/scenes/occluders.py); the held-out
views show the static scene alone, with the neutral look. Appearance codes take the looks, and
RobustNeRF's trimmed loss on 16 x 16 patches (train.patch_size) leaves the passers-by out
(docs/photo_collections.md).

  python train.py --config=configs/scenes/crowd.py --workdir=runs/crowd
"""

from nerf_jax.configs import fast


def get_config():
  config = fast.get_config()
  config.data.scene = "crowd"  # the built-in capture with passers-by and per-photo looks
  config.model.appearance_dims = 8  # a code of 8 numbers per training photo
  config.loss.robust.weight = 1.0  # RobustNeRF's trimmed loss: on patches, for the colour loss
  return config
