"""Real captures (rooms, gardens, objects with their surroundings): configs/fast.py in an
unbounded scene. The inner box holds the cameras (found from the data, data.scene_bound = -1);
space beyond it is contracted into twice the box (nerfacto's L-infinity contraction, which suits
grids), sampled linearly in disparity out to infinity.

  python train.py --config=capture --config.data.path=DIR --config.data.factor=4
"""

from nerf_jax.configs import fast


def get_config():
  config = fast.get_config()
  config.data.scene_bound = -1.0  # the inner box from the data (the cameras' box)
  config.data.contraction = "linf"  # all of space: beyond the box, contracted into twice it
  config.data.inner_fraction = 0.5  # half the samples inside the box, half out to infinity
  config.model.view_dependent = True  # real photos have highlights and reflections
  config.model.grid.resolutions = (32, 64, 128, 256)  # finer levels: the grids span 4x the box
  config.model.grid.features = 2  # features per lattice point (memory of the 256^3 level)
  config.train.max_seconds = 300.0  # five minutes; the schedule follows from it
  return config
