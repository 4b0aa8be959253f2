"""Real captures (rooms, gardens, objects with their surroundings): configs/fast.py in an
unbounded scene. The inner box is the subject's, found from the data (data.scene_bound = -1:
instant-ngp's unit cube, the sparse points' box, else the cameras'); space beyond it is
contracted into twice the box (nerfacto's L-infinity contraction, which suits grids) and
sampled linearly in disparity out to infinity; an occupancy grid over the contracted space
places the samples (as configs/detail.py in its box).

  python train.py --config=capture --config.data.path=DIR --config.data.factor=4
"""

from nerf_jax.configs import fast


def get_config():
  config = fast.get_config()
  config.data.scene_bound = -1.0  # the inner box from the data (the subject's box)
  config.data.contraction = "linf"  # all of space: beyond the box, contracted into twice it
  config.data.inner_fraction = 0.5  # half the candidate samples inside the box, half beyond
  config.model.view_dependent = True  # real photos have highlights and reflections
  config.num_samples = 32  # samples per ray, all in occupied cells
  config.occupancy.enabled = True  # sample where the occupancy grid says there is something
  config.occupancy.resolution = 64  # 64^3 cells over the contracted space
  config.occupancy.probes = 1  # one jittered probe per cell per refresh (they accumulate)
  config.train.batch_rays = 4096  # twice fast.py's rays: the samples per step stay the same
  config.train.lr = 2e-2  # as configs/detail.py
  config.train.max_seconds = 300.0  # five minutes; the schedule follows from it
  return config
