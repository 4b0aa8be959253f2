"""A short warm-up on a capture's training photos, shrunk, for what `--config=auto` can only
measure with a field: its renders of the training cameras against the photos
(transient_share.transient_share: passers-by leave residuals that one photo holds).

The warm-up is `configs/fast.py` with the plain loss and no codes, on the photos box-averaged to
at most WARM_UP_SIZE pixels a side, for WARM_UP_STEPS steps: after it the field shows the static
scene and not yet what only some photos show.
"""

import dataclasses
import math

import jax
import numpy as np

from nerf_jax.render import background, image_renderer
from nerf_jax.run import builders, config_lib, experiment_parts, from_data
from nerf_jax.run.signature import init_state
from nerf_jax.train import train_step as train_step_lib

WARM_UP_SIZE = 48  # the photos' larger side during the warm-up (docs/photo_collections.md)
WARM_UP_STEPS = 300  # steps of the warm-up
WARM_UP_RAYS = 1024  # rays a step


def box_shrunk(dataset, size):
  """`dataset` (one camera) with each image box-averaged by the integer factor that brings its
  larger side to at most `size` (its last rows and columns cropped to a multiple of it), the
  intrinsics scaled to match; depths dropped, masks kept only where the whole box is kept."""
  height, width = dataset.height, dataset.width
  f = max(1, math.ceil(max(height, width) / size))
  h, w = height // f, width // f

  def pool(a, reduce=np.mean):
    if a is None:
      return None
    a = np.asarray(a)[:, :h * f, :w * f]
    return reduce(a.reshape(a.shape[0], h, f, w, f, *a.shape[3:]), axis=(2, 4)).astype(a.dtype)

  fx, fy, cx, cy = dataset.intrinsics
  return dataclasses.replace(dataset, images=pool(dataset.images), accs=pool(dataset.accs),
                             masks=pool(dataset.masks, np.min), depths=None,
                             intrinsics=(fx / f, fy / f, cx / f, cy / f))


def warm_up_config(seed=0):
  """configs/fast.py for the warm-up: the plain colour loss, no codes, WARM_UP_STEPS steps."""
  config = config_lib.load("fast")
  config.seed = seed
  config.train.max_steps, config.train.max_seconds = WARM_UP_STEPS, 0.0
  config.train.batch_rays = WARM_UP_RAYS
  return config


def photos_and_renders(dataset, seed=0):
  """(photos, renders), float32 [N, h, w, 3] each: the training photos of `dataset` (one
  camera), shrunk (`box_shrunk`), on a black background, and the warm-up's renders of their
  cameras (the photo itself at masked pixels)."""
  train = box_shrunk(dataset, WARM_UP_SIZE)
  config = warm_up_config(seed)
  config.data.background = "black"
  near, far = from_data.bounds(config, train)
  config = from_data.with_scene_extent(config, train)
  exp = experiment_parts.assemble(config, train, train, near, far)
  state = init_state(exp)
  data = builders.make_train_data(exp)
  step = train_step_lib.make_train_step(**builders.train_step_args(exp))
  key = jax.random.PRNGKey(seed + 1)
  for _ in range(WARM_UP_STEPS):
    state, _ = step(state, data, key)
  draw = image_renderer.make_image_renderer(exp.renderer, exp.image)(state.variables)
  black = np.zeros(3, np.float32)
  photos = background.images_on_background(train, black)[1]
  renders = np.stack([np.asarray(draw(exp.rays(p), black)["rgb"]) for p in train.poses])
  if train.masks is not None:  # masked pixels are not the scene's to explain: no residual
    renders = np.where(np.asarray(train.masks)[..., None] > 0, renders, photos)
  return np.asarray(photos), renders
