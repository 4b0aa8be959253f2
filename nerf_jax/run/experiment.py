"""What a run is made of, built once for every entry point (training, rendering, benchmarks,
the viewer, tests): the config, the renderer, the optimiser, the datasets and the ray bounds;
and restoring all of it from a workdir. The wiring lives beside it: from_data.py (the config
completed from the data), components.py (each layer's settings and components), optimizer.py,
train_state.py (the state and its checkpoint signature); their names are importable from here
too, as they always were.
"""

import dataclasses
from typing import Any

import ml_collections
import optax

from nerf_jax.run import auto, config_lib
from nerf_jax.train import checkpoints
from nerf_jax.data import loaders
from nerf_jax.data.dataset import Dataset
from nerf_jax.render.image_renderer import ImageSettings
from nerf_jax.cameras.rays import camera_rays
from nerf_jax.render.renderer import RayRenderer
from nerf_jax.run.components import (  # re-exported
    batch_settings, cached_train_step, data_settings, encoding_family, eval_settings,
    image_settings, loss_terms, make_evaluator, make_field, make_ray_renderer, make_sampler,
    make_train_data, make_train_step, network_settings, rays_per_step, step_settings,
    training_renderer)
from nerf_jax.run.from_data import (  # re-exported
    CUT_SHARE, HULL_RESOLUTION, NDC_MARGIN, bounds, pixel_center, warn_if_cut, with_ndc_box,
    with_scene_extent, with_visual_hull)
from nerf_jax.run.optimizer import (  # re-exported
    make_optimizer, make_schedule, optimizer_for, schedule_steps)
from nerf_jax.run.train_state import (  # re-exported
    init_state, model_signature, state_template, upgrade_state_dict)
from nerf_jax.train.state import TrainState  # re-exported


__all__ = [
    'CUT_SHARE', 'HULL_RESOLUTION', 'NDC_MARGIN',
    'Experiment', 'TrainState', 'TrainingError', 'batch_settings', 'bounds',
    'cached_train_step', 'data_settings', 'encoding_family', 'eval_settings', 'image_settings',
    'init_state', 'loss_terms', 'make_evaluator', 'make_field', 'make_optimizer',
    'make_ray_renderer', 'make_sampler', 'make_schedule', 'make_train_data', 'make_train_step',
    'model_signature', 'network_settings', 'optimizer_for', 'pixel_center', 'rays_per_step',
    'restore', 'schedule_steps', 'setup', 'state_template', 'step_settings',
    'training_renderer', 'upgrade_state_dict', 'warn_if_cut', 'with_ndc_box',
    'with_scene_extent', 'with_visual_hull'
]

class TrainingError(RuntimeError):
  """Training cannot go on (non-finite loss, bad config); the message says why and what to do."""


@dataclasses.dataclass
class Experiment:
  """A config and what it builds. near, far: the ray bounds (z-depth; [0, 1] in NDC).
  renderer: the RayRenderer (field + sampler); image: how whole images are rendered."""
  config: ml_collections.ConfigDict
  renderer: RayRenderer
  image: ImageSettings
  tx: optax.GradientTransformation
  train_ds: Dataset
  test_ds: Dataset
  near: float
  far: float
  hull: Any = None  # float32 [R, R, R] visual hull on the occupancy grid's cells (data.visual_hull)

  def camera(self, scale=1.0):
    """(height, width, intrinsics) of the training camera with `scale` times its pixels per side
    (same field of view: focal lengths and principal point scale with the image)."""
    ds = self.train_ds
    height, width = max(1, round(ds.height * scale)), max(1, round(ds.width * scale))
    sx, sy = width / ds.width, height / ds.height
    fx, fy, cx, cy = ds.intrinsics
    return height, width, (fx * sx, fy * sy, cx * sx, cy * sy)

  @property
  def pixel_center(self):
    """Where in its pixel each ray passes: config.data.pixel_center, or the data's own (-1)."""
    return pixel_center(self.config, self.train_ds)

  def rays(self, pose, camera=None):
    """Rays [H, W] of `pose` (float32 [4, 4] camera-to-world) through `camera` (default: the
    training camera), as the config asks (pixel centres, NDC)."""
    height, width, intrinsics = camera or self.camera()
    return camera_rays(height, width, intrinsics, pose, self.near, self.far,
                       self.pixel_center, self.config.data.ndc)


def setup(config):
  """The Experiment of `config`: loads the data, builds the renderer and the optimiser."""
  config = config_lib.upgrade(config)
  make_ray_renderer(config)  # a bad model or sampler setting fails before the data loads
  train_ds, test_ds = loaders.load_dataset(data_settings(config.data))
  if config.auto:
    config = auto.auto_config(config, train_ds)
  pixel_center(config, train_ds)  # a bad value fails here, naming the field
  near, far = bounds(config, train_ds)
  config = with_scene_extent(config, train_ds)
  config = with_ndc_box(config, train_ds, near, far)
  config, hull = with_visual_hull(config, train_ds)
  exp = Experiment(config, make_ray_renderer(config, len(train_ds)), image_settings(config),
                   optimizer_for(config), train_ds, test_ds, near, far, hull)
  warn_if_cut(exp)
  return exp


def restore(workdir, with_meta=False):
  """(Experiment, TrainState[, meta]) of the newest checkpoint in `workdir`, under the config
  the run saved (completed with today's defaults, see config_lib.load_saved)."""
  config = config_lib.load_saved(workdir)
  path = checkpoints.latest_path(workdir)
  if path is None:
    raise TrainingError(f"no checkpoint in {checkpoints.checkpoint_dir(workdir)}: "
                        "train first (python train.py --workdir=...)")
  exp = setup(config)
  state, meta = checkpoints.restore_with_meta(path, state_template(exp), model_signature(config),
                                              upgrade_state_dict)
  return (exp, state, meta) if with_meta else (exp, state)
