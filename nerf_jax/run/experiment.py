"""What a run is made of, built once for every entry point (training, rendering, benchmarks,
the viewer, tests): the config, the renderer, the optimiser, the datasets and the ray bounds;
and restoring all of it from a workdir. The wiring it calls lives beside it: from_data.py (the
config completed from the data), builders.py (each layer's settings and components),
experiment_parts.py (the Experiment these make) and signature.py (what a checkpoint records:
the model signature, a fresh state, its template).
"""

import dataclasses

import jax

from nerf_jax.data import loaders
from nerf_jax.run import builders, config_lib, experiment_parts, from_data, subject
from nerf_jax.run.auto import auto, resolution
from nerf_jax.run.signature import model_signature, state_template
from nerf_jax.train import checkpoints
from nerf_jax.train.state import upgrade_state_dict


class TrainingError(RuntimeError):
  """Training cannot go on (non-finite loss, bad config); the message says why and what to do."""


def load_decided(config):
  """(config, train Dataset, test Dataset): the data of `config` loaded, and with config.auto
  the config auto decides from it (auto.auto_config; auto off in the result)."""
  config = config_lib.upgrade(config)
  builders.make_ray_renderer(config)  # a bad model or sampler setting fails before the data
  settings = builders.data_settings(config.data)
  if config.auto:  # the photos' size is decided before they are read at full size
    factor = resolution.factor_effects(config, jax.default_backend())
    settings = dataclasses.replace(settings, factor=factor[0].get("data.factor", settings.factor))
  train_ds, test_ds = loaders.load_dataset(settings)
  if config.auto:  # before the background: auto sets its own from the data
    config = auto.auto_config(config, train_ds, before_loading=factor)
  return config, train_ds, test_ds


def setup(config):
  """The Experiment (experiment_parts.py) of `config`: loads the data, completes the config,
  builds the renderer and the optimiser."""
  config, train_ds, test_ds = load_decided(config)
  config = from_data.with_background(config)
  from_data.pixel_center(config, train_ds)  # a bad value fails here, naming the field
  config, train_ds, test_ds = subject.with_subject(config, train_ds, test_ds)
  train_ds = from_data.with_photo_zoom(config, train_ds)
  near, far = from_data.bounds(config, train_ds)
  train_ds, test_ds = from_data.with_focus(config, train_ds, test_ds)
  config = from_data.with_scene_extent(config, train_ds)
  config = from_data.with_ndc_box(config, train_ds, near, far)
  config, hull = from_data.with_visual_hull(config, train_ds)
  exp = experiment_parts.assemble(config, train_ds, test_ds, near, far, hull)
  from_data.warn_if_cut(exp)
  return exp


def restore(workdir, with_meta=False, overrides=None):
  """(Experiment, TrainState[, meta]) of the newest checkpoint in `workdir`, under the config
  the run saved (completed with today's defaults, see config_lib.load_saved) with `overrides`
  ({dotted field: value}, e.g. render.py's --config.eval.fit_steps) set on top."""
  config = config_lib.load_saved(workdir)
  for field, value in (overrides or {}).items():
    config_lib.set_field(config, field, value)
  path = checkpoints.latest_path(workdir)
  if path is None:
    raise TrainingError(f"no checkpoint in {checkpoints.checkpoint_dir(workdir)}: "
                        "train first (python train.py --workdir=...)")
  exp = setup(config)
  state, meta = checkpoints.restore_with_meta(path, state_template(exp), model_signature(config),
                                              upgrade_state_dict)
  return (exp, state, meta) if with_meta else (exp, state)
