"""`forward`: an LLFF-like capture — cameras on a small plane looking down -z at objects before a
back wall. Every ray ends on the wall, so depth spans a wide range: rays are mapped to normalized
device coordinates (NDC), where sampling uniformly in t in [0, 1] is sampling uniformly in
disparity. Lambertian, so no view branch. Videos follow a spiral instead of an orbit.

  python train.py --config=configs/scenes/forward.py --workdir=runs/forward
"""

from nerf_jax.configs import default


def get_config():
  config = default.get_config()
  config.data.scene = "forward"  # the built-in forward-facing scene
  config.data.ndc = True  # NDC rays; near/far become 0 and 1
  config.data.lindisp = False  # NDC's uniform t is already uniform in disparity
  config.data.holdout_from = -1  # the last 20% of the views are test views
  config.model.view_dependent = False  # Lambertian
  config.num_fine_samples = 0  # opaque surfaces
  return config
