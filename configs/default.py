"""The recommended setup: train on the built-in `diffuse` scene in a few minutes on a 2-core CPU.

  python train.py --config=configs/default.py --workdir=runs/default
  python train.py --config=configs/default.py --config.num_samples=128 --workdir=runs/s128

Every setting is declared once, with its default and its one-line comment, in the settings
dataclass of the part that reads it; the library's schema (nerf_jax/run/schema.py) builds each
section from them, so a field here and its dataclass cannot disagree, and a key that none of
its section's dataclasses declares is refused (run/builders.check_config). The sections, and
the dataclasses (under nerf_jax/) that declare their settings:

  config             run/settings.RunSettings (seed, auto*), samplers/registry.Settings
                     (num_samples, sampler), render/renderer.FineSettings (num_fine_samples),
                     fields/encodings/posenc.Settings (pos_encode_dims, the positions' bands),
                     fields/protocol.DirectionSettings (dir_encode_dims, dir_encoding)
  config.data        data/data_settings.DataSettings (the images and cameras loaded),
                     cameras/scene_settings.SceneSettings (how rays see the scene: box,
                     bounds, spacing)
  config.model       fields/registry.Parts (the parts' names), fields/protocol.NetworkSettings
                     (what every network shares), fields/networks/mlp.Settings (depth, skips),
                     fields/field.Settings (noise), render/renderer.Settings
  config.model.transient    fields/networks/transient_head.Settings (NeRF-W's, dims 0 = off)
  config.occupancy   samplers/occupancy.OccupancySettings
  config.loss        train/losses.Settings (the terms, in the order they are added)
  config.train       run/settings.LoopSettings, train/train_batches.BatchSettings,
                     train/optimizer.OptimizerSettings, train/train_step.StepSettings
  config.render      render/image_renderer.ImageSettings, run/settings.OutputSettings
  config.eval        evaluate/evaluation.Settings (how held-out views are scored)
  config.viewer      run/settings.ViewerSettings

A built-in component's own settings are its own section, its module's `Settings`
(schema.COMPONENTS):

  config.model.grid, config.model.hash, config.model.tensorf    fields/encodings/<name>.Settings
  config.proposal    samplers/proposal.Settings
  config.loss.<term> (colour, distortion, pose_prior, total_variation, transient, robust,
                     masked_empty, depth)    train/losses/<term>.Settings
"""

from nerf_jax.run import schema


def get_config():
  config = schema.defaults()
  return config
