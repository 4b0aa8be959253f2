"""What a run is made of, built once for every entry point (training, rendering, benchmarks,
the viewer, tests): the config, the model, the optimiser, the datasets and the ray bounds; the
train state and its checkpoint signature; and restoring all of it from a workdir.
"""

import dataclasses
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import ml_collections
import optax

from nerf_jax import budget, checkpoints, config_lib, field, occupancy
from nerf_jax.data import loaders
from nerf_jax.data.dataset import Dataset
from nerf_jax.model import make_model
from nerf_jax.rays import camera_rays


class TrainingError(RuntimeError):
  """Training cannot go on (non-finite loss, bad config); the message says why and what to do."""


@flax.struct.dataclass
class TrainState:
  step: jnp.ndarray  # int32 [], steps taken
  params: dict  # {'coarse': ..., ['fine': ...], ['occupancy': ...]}
  opt_state: optax.OptState
  bad_step: jnp.ndarray  # int32 [], first step whose loss or gradient was non-finite, -1 if none


@dataclasses.dataclass
class Experiment:
  """A config and what it builds. near, far: the ray bounds (z-depth; [0, 1] in NDC)."""
  config: ml_collections.ConfigDict
  model: Any
  tx: optax.GradientTransformation
  train_ds: Dataset
  test_ds: Dataset
  near: float
  far: float

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
  """The Experiment of `config`: loads the data, builds the model and the optimiser."""
  train_ds, test_ds = loaders.load_dataset(config.data)
  pixel_center(config, train_ds)  # a bad value fails here, naming the field
  near, far = bounds(config, train_ds)
  return Experiment(config, make_model(config.model), make_optimizer(config.train), train_ds,
                    test_ds, near, far)


def pixel_center(config, dataset):
  """config.data.pixel_center, or with -1 the dataset's (what its images were taken through);
  ValueError naming the field for any other value outside [0, 1]."""
  value = config.data.pixel_center
  if value == -1:
    return float(dataset.pixel_center)
  if not 0.0 <= value <= 1.0:
    raise ValueError(f"config.data.pixel_center={value}: use -1 (the data's own), 0 (pixel "
                     "corners) or 0.5 (pixel centres)")
  return float(value)


def bounds(config, dataset):
  """(near, far): [0, 1] in NDC, else the config's overrides where set, else the dataset's."""
  if config.data.ndc:
    return 0.0, 1.0  # NDC rays run from the near plane (0) to infinity (1)
  return (float(config.data.near or dataset.near), float(config.data.far or dataset.far))


def make_schedule(train_config, planned_steps=None):
  """count -> learning rate: linear warm-up from 0 to `lr` over `warmup_steps`, then exponential
  decay reaching `lr_final` at the planned steps and staying there (a time-budget run may take a
  few more).

  planned_steps: None for `budget.planned_steps` of the config, or an int32 [] (possibly traced:
  a time budget's fitted length, see budget.py, so one compiled step serves any length), over
  which warm-up keeps its share of the config's planned steps (as `budget.fit_schedule`).
  """
  tc = train_config
  planned, warmup = budget.planned_steps(tc), tc.warmup_steps
  if planned_steps is not None:
    warmup = jnp.round(tc.warmup_steps / max(planned, 1) * planned_steps)
    planned = planned_steps

  def schedule(count):
    count = jnp.asarray(count, jnp.float32)
    progress = jnp.clip((count - warmup) / jnp.maximum(planned - warmup, 1), 0.0, 1.0)
    decayed = tc.lr * (tc.lr_final / tc.lr) ** progress
    if tc.warmup_steps <= 0:
      return decayed
    return jnp.where(count < warmup, tc.lr * count / jnp.maximum(warmup, 1), decayed)
  return schedule


def make_optimizer(train_config, planned_steps=None):
  """Adam on the schedule (see `make_schedule`), with optional global-norm gradient clipping."""
  adam = optax.adam(make_schedule(train_config, planned_steps))
  if train_config.grad_clip > 0:
    return optax.chain(optax.clip_by_global_norm(train_config.grad_clip), adam)
  return adam


def model_signature(config):
  """Config fields that fix the parameter shapes; a checkpoint only restores under the same."""
  m = config.model
  signature = {"pos_encode_dims": config.pos_encode_dims,
               "dir_encode_dims": config.dir_encode_dims, "depth": m.depth, "width": m.width,
               "skip_layers": list(m.skip_layers), "view_dependent": m.view_dependent,
               "view_width": m.view_width, "networks": list(field.network_names(config))}
  if m.encoding != "posenc":  # only then, so older checkpoints stay valid
    signature.update(encoding=m.encoding, grid_resolutions=list(m.grid_resolutions),
                     grid_features=m.grid_features)
  if m.encoding == "hash":  # the table's shape and the meaning of its rows
    signature.update(hash_levels=m.hash_levels, hash_log2_size=m.hash_log2_size,
                     hash_features=m.hash_features, hash_base_resolution=m.hash_base_resolution,
                     hash_max_resolution=m.hash_max_resolution)
  if occupancy.enabled(config):
    signature.update(occupancy_resolution=config.occupancy.resolution)
  return signature


def init_state(exp):
  """A fresh TrainState of `exp` (parameters from config.seed)."""
  params = field.init_params(exp.model, exp.config, jax.random.PRNGKey(exp.config.seed))
  return TrainState(step=jnp.array(0, jnp.int32), params=params, opt_state=exp.tx.init(params),
                    bad_step=jnp.array(-1, jnp.int32))


def state_template(exp):
  """The structure of `init_state` (shapes and dtypes, nothing computed): what a checkpoint
  restores into, in a fraction of a second instead of initialising every parameter eagerly."""
  return jax.eval_shape(lambda: init_state(exp))


def restore(workdir, with_meta=False):
  """(Experiment, TrainState[, meta]) of the newest checkpoint in `workdir`, under the config
  the run saved (completed with today's defaults, see config_lib.load_saved)."""
  config = config_lib.load_saved(workdir)
  path = checkpoints.latest_path(workdir)
  if path is None:
    raise TrainingError(f"no checkpoint in {checkpoints.checkpoint_dir(workdir)}: "
                        "train first (python train.py --workdir=...)")
  exp = setup(config)
  state, meta = checkpoints.restore_with_meta(path, state_template(exp), model_signature(config))
  return (exp, state, meta) if with_meta else (exp, state)
