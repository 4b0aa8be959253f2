"""An Experiment: a config and the parts it builds on its datasets (the renderer, the image
settings, the optimiser, the ray bounds), and `assemble`, which builds them. experiment.py loads
the data and completes the config (auto included) before it assembles; auto's warm-up
(warm_up.py) assembles one of its own on shrunk photos, so this lies below both.
"""

import dataclasses
from typing import Any

import ml_collections
import optax

from nerf_jax.cameras.rays import camera_rays
from nerf_jax.data.dataset import Dataset
from nerf_jax.render.image_renderer import ImageSettings
from nerf_jax.render.renderer import RayRenderer
from nerf_jax.run import builders, from_data
from nerf_jax.train import optimizer


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
  hull: Any = None  # (float32 [R, R, R], bound): visual hull on [-bound, bound]^3, data.visual_hull

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


def assemble(config, train_ds, test_ds, near, far, hull=None):
  """The Experiment of a completed `config` on loaded datasets: its renderer, image settings and
  optimiser built from the config. near, far, hull: as Experiment holds them."""
  return Experiment(config, builders.make_ray_renderer(config, len(train_ds)),
                    builders.image_settings(config),
                    optimizer.make_optimizer(builders.optimizer_settings(config)), train_ds,
                    test_ds, near, far, hull)
