"""Forward-facing real captures (LLFF folders: poses_bounds.npy + images_N/): configs/fast.py's
dense grids in normalized device coordinates, with the view branch for real materials. Chosen by
measurement on LLFF's fern against the NDC MLP (docs/quality_per_second.md).

  python train.py --config=configs/llff.py --config.data.path=DIR --config.data.factor=8
"""

from nerf_jax.configs import fast


def get_config():
  config = fast.get_config()
  config.data.ndc = True  # NDC rays: t in [0, 1] is uniform in disparity, far = infinity
  config.data.scene_bound = 0.0  # no box: NDC space is already bounded
  config.data.holdout_from = -1  # LLFF's protocol: every 8th view is a test view
  # NDC coordinates of the training rays reach about ±1.4 (x), ±1.25 (y) beyond the reference
  # camera's frustum (measured on fern); z spans [-1, 1].
  config.model.grid_box = (-1.45, -1.3, -1.0, 1.45, 1.3, 1.0)
  config.model.view_dependent = True  # real materials shine
  config.dir_encode_dims = 4  # the paper's 4 bands for directions
  config.train.random_background = False  # photos: no opacity
  config.train.max_seconds = 600.0  # ten minutes; the step budget and schedule follow from it
  config.render.video_path = "auto"  # the spiral of forward-facing captures
  return config
