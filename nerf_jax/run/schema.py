"""The config's schema: each section (a dotted path) and the settings dataclasses that declare
its keys, and the default config built from them.

Every setting is declared once, with its default and its one-line comment, in the settings
dataclass of the part that reads it; `defaults` builds each section from them, so a config
field and its dataclass cannot disagree. A component's own settings are its own section
(`COMPONENTS`: config.model.<encoding>, config.<sampler>, config.loss.<term>); the other
sections (`SECTIONS`) are shared by the dataclasses listed for them, and a key none of them
declares is refused (run/builders.check_config). configs/default.py is `defaults()`.
"""

import ml_collections

from nerf_jax.backend import components
from nerf_jax.cameras import scene_settings
from nerf_jax.data import data_settings
from nerf_jax.evaluate import evaluation
from nerf_jax.fields import field, protocol, registry
from nerf_jax.fields.encodings import posenc
from nerf_jax.fields.networks import mlp
from nerf_jax.fields.networks import transient_head
from nerf_jax.render import image_renderer, renderer
from nerf_jax.run import settings
from nerf_jax.samplers import occupancy
from nerf_jax.samplers import registry as samplers
from nerf_jax.train import losses, optimizer, train_batches, train_step

# Each shared section (dotted path, '' = the top level) and the dataclasses that declare its
# settings.
SECTIONS = {
    # seed, auto*; num_samples (NUM_SAMPLES), sampler; num_fine_samples; pos_encode_dims
    # (POS_ENCODE_DIMS, the positions' bands); dir_encode_dims, dir_encoding (the directions').
    "": (settings.RunSettings, samplers.Settings, renderer.FineSettings, posenc.Settings,
         protocol.DirectionSettings),
    # The images and cameras loaded; how rays see the scene (box, bounds, spacing).
    "data": (data_settings.DataSettings, scene_settings.SceneSettings),
    # The parts' names; what every network shares (width, view_*, dtype, appearance, the
    # lattices' box); the MLP's depth and skips; the field's noise; the renderer's use of it.
    "model": (registry.Parts, protocol.NetworkSettings, mlp.Settings, field.Settings,
              renderer.Settings),
    "model.transient": (transient_head.Settings,),  # NeRF-W's transient head (dims 0 = off)
    "occupancy": (occupancy.OccupancySettings,),  # the occupancy grid (enabled, then its grid)
    "loss": (losses.Settings,),  # the order of the terms; each term's section is its own
    "train": (settings.LoopSettings, train_batches.BatchSettings, optimizer.OptimizerSettings,
              train_step.StepSettings),
    "render": (image_renderer.ImageSettings, settings.OutputSettings),
    # How held-out views are scored: NeRF-W's left-half appearance fit or the mean code.
    "eval": (evaluation.Settings,),
    "viewer": (settings.ViewerSettings,),
}

# The registries whose built-in components have sections of their own (Registry.section_path):
# the lattice encodings' model.grid, model.hash, model.tensorf; the proposal sampler's
# config.proposal; each loss term's config.loss.<term>.
COMPONENTS = (registry.ENCODINGS, registry.NETWORKS, samplers.REGISTRY, losses.REGISTRY)


def component_sections():
  """{dotted path: (settings dataclass,)} of every built-in component with a section of its
  own."""
  found = {}
  for reg in COMPONENTS:
    for name in reg.names():
      record = reg.lookup(name)
      if record.settings is not None and record.strict:
        found[reg.section_path(record)] = (record.settings,)
  return found


def all_sections():
  """{dotted path: settings dataclasses} of every section: the shared ones (`SECTIONS`) and
  the built-in components' own (`component_sections`)."""
  return {**SECTIONS, **component_sections()}


def defaults():
  """The default config (a ConfigDict): every section of `all_sections`, each setting at its
  dataclass's default."""
  config = ml_collections.ConfigDict()
  for path, classes in all_sections().items():
    node = config
    for part in filter(None, path.split(".")):
      if part not in node:
        node[part] = ml_collections.ConfigDict()
      node = node[part]
    node.update(components.section(*classes))
  return config
