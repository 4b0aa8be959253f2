"""`landmark`: a tourist photo collection (nerf_jax/data/scenes/landmark.py): a monument 1 high
on a square with façades and a sky, seen from 2 to 9 times its size, each training photo with
its own zoom (focal spread 3x) and barrel lens (k1 -0.5..-0.2) while the data stores one pinhole
(the median focal), per-photo looks, passers-by in 60% of the photos, and masks that keep the
monument alone. configs/capture.py (the box from the data, an unbounded capture) with
per-photo appearance codes; the masks leave the passers-by, the ground and the sky out
(docs/photo_collections.md).

  python train.py --config=configs/scenes/landmark.py --workdir=runs/landmark
"""

from nerf_jax.configs import capture


def get_config():
  config = capture.get_config()
  config.data.scene = "landmark"  # the built-in photo collection
  config.model.appearance_dims = 8  # a code of 8 numbers per training photo
  config.model.view_dependent = False  # Lambertian: no highlights to model
  config.train.max_seconds = 0.0  # a step budget (default_steps) instead of capture's 5 minutes
  return config
