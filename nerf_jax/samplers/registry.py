"""Samplers by name: adding one is a module of samplers/ and its config section.

A sampler other than the built-in `sampler.Sampler` (stratified or occupancy placement) lives in
`nerf_jax/samplers/<name>.py`, which calls `register(name, build)` when it is imported; the
config selects it with `config.sampler = '<name>'` and sets it in its own section
`config.<name>` (run/experiment.make_sampler). `build(name, base, section)` imports the module
on first use, so nothing imports every sampler up front.

build(base, section) -> sampler: `base` is the built-in Sampler of the config (num_samples,
scene_bound, contraction, inner_fraction: what every placement shares), `section` a plain dict
of the sampler's config section. It returns an object with the interface of `sampler.Sampler`
(`generate`, `init`, `signature`, `loss_terms`, `marchable` besides `bounds` and
`unit_distance`; subclassing Sampler gives them all) and raises ValueError naming the field
for a setting it cannot use.
"""

import importlib

_BUILDERS = {}


def register(name, build):
  """Make `build(base, section) -> sampler` the sampler called `name` (config.sampler)."""
  _BUILDERS[name] = build


def build(name, base, section):
  """The sampler `name` built from `base` (sampler.Sampler) and `section` (dict), its module
  imported first if needed; ValueError naming config.sampler for a name no module registers."""
  if name not in _BUILDERS:
    try:
      importlib.import_module(f"nerf_jax.samplers.{name}")
    except ImportError:
      pass  # not a module of samplers/: the error below names the choices
  if name not in _BUILDERS:
    choices = ", ".join(repr(n) for n in ("", *sorted(_BUILDERS)))
    raise ValueError(f"config.sampler={name!r}: no such sampler; use {choices} (a module "
                     "nerf_jax/samplers/<name>.py that calls registry.register)")
  return _BUILDERS[name](base, section)
