"""Samplers by name (config.sampler), through the one registry shape (backend/components.py).

A sampler's module defines `SAMPLER = registry.SamplerKind(build)`. The built-ins are
'placement' (placement.py: stratified, or occupancy placement; config.sampler = '' means it)
and 'proposal' (proposal.py); a new one is a module anywhere, chosen with config.sampler = its
dotted module path, or given a short name with `REGISTRY.register(name, module path)`. Its
settings are its own config section, config.<name> (the module name for a dotted path);
run/components.make_sampler builds it. A module is imported the first time it is asked for.

build(base, section) -> sampler: `base` is the built-in placement.Sampler of the config
(num_samples, scene_bound, contraction, inner_fraction: what every placement shares), `section`
a plain dict of the sampler's config section. It returns an object with the interface of
`placement.Sampler` (`generate`, `init`, `signature`, `loss_terms`, `marchable` besides
`bounds` and `unit_distance`; subclassing Sampler gives them all) and raises ValueError naming
the field for a setting it cannot use.
"""

import dataclasses
from typing import Callable

from nerf_jax.backend import components

# The built-in placement's name; config.sampler = '' means it.
BUILTIN = "placement"

REGISTRY = components.Registry("sampler", "config.sampler", "SAMPLER", {
    BUILTIN: "nerf_jax.samplers.placement", "proposal": "nerf_jax.samplers.proposal"})


@dataclasses.dataclass(frozen=True)
class SamplerKind:
  """A sampler module's record (its SAMPLER). build(base, section) -> sampler (see above)."""
  build: Callable


def section_name(name):
  """The config section of the sampler `name` (a short name or a dotted module path)."""
  return (name or BUILTIN).rsplit(".", 1)[-1]


def build(name, base, section):
  """The sampler `name` ('' = the built-in placement) built from `base` (placement.Sampler)
  and `section` (dict); ValueError naming config.sampler for a name that names none."""
  return REGISTRY.lookup(name or BUILTIN).build(base, section)
