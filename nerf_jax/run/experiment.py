"""What a run is made of, built once for every entry point (training, rendering, benchmarks,
the viewer, tests): the config, the renderer, the optimiser, the datasets and the ray bounds;
and restoring all of it from a workdir. The wiring it calls lives beside it: from_data.py (the
config completed from the data), components.py (each layer's settings and components) and
signature.py (what a checkpoint records: the model signature, a fresh state, its template).
"""

import dataclasses
from typing import Any

import ml_collections
import optax

from nerf_jax.cameras.rays import camera_rays
from nerf_jax.data import loaders
from nerf_jax.data.dataset import Dataset
from nerf_jax.render.image_renderer import ImageSettings
from nerf_jax.render.renderer import RayRenderer
from nerf_jax.run import auto, components, config_lib, from_data
from nerf_jax.run.signature import model_signature, state_template
from nerf_jax.train import checkpoints, optimizer
from nerf_jax.train.state import upgrade_state_dict


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

  def camera(self, scale=1.0, image=None, dataset=None):
    """(height, width, intrinsics) of the training camera with `scale` times its pixels per side
    (same field of view: focal lengths and principal point scale with the image).

    image: int or None, take the camera of image `image` of `dataset` (a Dataset; None = the
    training images; Dataset.cameras) instead of the shared one (with per-image cameras, that
    of training image 0)."""
    if image is None:
      ds = self.train_ds
      base_height, base_width, intrinsics = ds.height, ds.width, ds.intrinsics
    else:
      ds = self.train_ds if dataset is None else dataset
      base_height, base_width, intrinsics = ds.cameras.camera(image)
      if ds.image_cameras is None:  # one camera: its intrinsics exactly as the data gives them
        intrinsics = ds.intrinsics
    height, width = max(1, round(base_height * scale)), max(1, round(base_width * scale))
    sx, sy = width / base_width, height / base_height
    fx, fy, cx, cy = intrinsics
    return height, width, (fx * sx, fy * sy, cx * sx, cy * sy)

  @property
  def pixel_center(self):
    """Where in its pixel each ray passes: config.data.pixel_center, or the data's own (-1)."""
    return from_data.pixel_center(self.config, self.train_ds)

  def rays(self, pose, camera=None):
    """Rays [H, W] of `pose` (float32 [4, 4] camera-to-world) through `camera` (height, width,
    intrinsics; default: the training camera; an image's own: `camera(image=i, dataset=ds)`),
    as the config asks (pixel centres, NDC), with their radii when the field reads cones
    (Field.cones)."""
    height, width, intrinsics = camera or self.camera()
    return camera_rays(height, width, intrinsics, pose, self.near, self.far,
                       self.pixel_center, self.config.data.ndc,
                       with_radii=self.renderer.field.cones)


def setup(config):
  """The Experiment of `config`: loads the data, builds the renderer and the optimiser."""
  config = config_lib.upgrade(config)
  components.make_ray_renderer(config)  # a bad model or sampler setting fails before the data
  train_ds, test_ds = loaders.load_dataset(components.data_settings(config.data))
  if config.auto:
    config = auto.auto_config(config, train_ds)
  from_data.pixel_center(config, train_ds)  # a bad value fails here, naming the field
  near, far = from_data.bounds(config, train_ds)
  train_ds, test_ds = from_data.with_focus(config, train_ds, test_ds)
  config = from_data.with_scene_extent(config, train_ds)
  config = from_data.with_ndc_box(config, train_ds, near, far)
  config, hull = from_data.with_visual_hull(config, train_ds)
  exp = Experiment(config, components.make_ray_renderer(config, len(train_ds)),
                   components.image_settings(config),
                   optimizer.make_optimizer(components.optimizer_settings(config)), train_ds,
                   test_ds, near, far, hull)
  from_data.warn_if_cut(exp)
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
