"""Samplers by name (config.sampler), through the one registry shape (backend/components.py).

A sampler's module defines `SAMPLER = components.Component(name, Settings, build)`. The built-ins are
'placement' (placement.py: stratified, or occupancy placement; config.sampler = '' means it)
and 'proposal' (proposal.py); a new one is a module anywhere, chosen with config.sampler = its
dotted module path, or given a short name with `REGISTRY.register(name, module path)`. Its
settings are its own config section, config.<name> (the record's name), read strictly;
run/builders.make_sampler builds it. A module is imported the first time it is asked for.

build(settings, base) -> sampler: `settings` its settings dataclass (None if it has none),
`base` the built-in placement.Sampler of the config (num_samples, scene_bound, contraction,
inner_fraction: what every placement shares). It returns an object with the interface of
`placement.Sampler` (`generate`, `init`, `signature`, `loss_terms`, `marchable` besides
`bounds` and `unit_distance`; subclassing Sampler gives them all) and raises ValueError naming
the field for a setting it cannot use.
"""

import dataclasses

from nerf_jax.backend import components

# The built-in placement's name; config.sampler = '' means it.
BUILTIN = "placement"

REGISTRY = components.Registry("sampler", "config.sampler", "SAMPLER", "", {
    BUILTIN: "nerf_jax.samplers.placement", "proposal": "nerf_jax.samplers.proposal"})


@dataclasses.dataclass(frozen=True)
class Settings:
  """config's top-level fields of the samples per ray and the sampler that places them."""
  num_samples: int = 32  # NUM_SAMPLES: stratified (coarse) samples per ray
  sampler: str = ""  # '' = stratified / occupancy placement; 'proposal' (config.proposal)


def record(name):
  """The record (components.Component) of the sampler `name` ('' = the built-in placement);
  ValueError naming config.sampler for a name that names none."""
  return REGISTRY.lookup(name or BUILTIN)
