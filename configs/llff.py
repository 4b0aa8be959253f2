"""LLFF folders (forward-facing real photos, e.g. fern): NDC rays and dense grids.

configs/fast.py's grids and tiny MLP head in normalized device coordinates, where the photos'
frustum fills x, y in [-1, 1] and depth is z in [-1, 1] (uniform in disparity). The grids cover
the box of all the training rays in NDC, found from the data (from_data.with_ndc_box).
Measured on fern in docs/quality_per_second.md, with what lost there.

  python train.py --config=configs/llff.py --config.data.path=DIR --config.data.factor=8
"""

from nerf_jax.configs import fast


def get_config():
  config = fast.get_config()
  config.data.ndc = True  # forward-facing: NDC rays, t in [0, 1] uniform in disparity
  config.data.scene_bound = 0.0  # NDC's t in [0, 1] already spans the frustum: no box cut
  config.model.view_dependent = True  # real photos have some gloss
  config.dir_encode_dims = 4  # the paper's 4 bands for directions
  config.train.random_background = False  # photos have no opacity to composite over
  config.loss.total_variation.weight = 0.0  # total variation of the tables
  config.train.lr_final = 1e-3  # a tenth of lr at the end (detail.py's; fern, measured)
  config.train.adam_b2 = 0.99  # Adam's faster second-moment decay, as detail.py
  config.train.max_seconds = 600.0  # ten minutes; the step budget and schedule follow from it
  return config
