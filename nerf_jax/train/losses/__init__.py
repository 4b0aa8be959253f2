"""The training loss as a list of named terms, one pure function each, found by name.

A term is called as term(inputs) with a `LossInputs` and returns (loss: float32 [], stats: dict
of float32 or int32 [] scalars to log); its `name` (str) namespaces its stats. The step adds the
terms' losses in their order (`total`) and logs every stat as '<name>/<stat>' (the colour term's
'colour/psnr', the proposal sampler's 'interlevel/unweighted').

A term is one module defining `LOSS = losses.Loss(name, Settings, build)` (a `Loss` record):
`config.loss.terms` lists the run's terms, in the order they are added, by their registered
name (`REGISTRY`: colour, distortion, pose_prior, total_variation, transient, robust,
masked_empty, depth, the modules of this package) or the dotted path of any importable module;
each term's settings are its own section, `config.loss.<name>` (docs/extending.md, "Adding a
loss term"). The entry layer builds them (run/builders.loss_terms), adds 'transient' where the
field has a transient head, and appends the sampler's own terms (its `loss_terms()`). A term
whose class has `replaces_colour = True` (robust) is itself the photometric loss: beside it the
entry layer builds the colour term with weight 0 (its PSNR only), so the two are never added.

A term with `keypoint_rays` > 0 (depth) asks for keypoint rays: each step then also draws that
many observations of the sparse points (the most any term asks for; train_batches.Keypoints),
renders their rays with the same parameters, and hands their outputs and targets to every term
(LossInputs.keypoint_outputs, keypoints); the entry layer fills TrainData.keypoints. No term
asks: nothing of them is built, drawn or rendered.
"""

import dataclasses
from typing import Any, Callable, Tuple

import flax.struct
import jax.numpy as jnp

from nerf_jax.backend import components


@flax.struct.dataclass
class LossInputs:
  """What a loss term may look at, for one batch of B rays.

  outputs: the renderer's outputs {'coarse': ..., ['fine': ...], ['sampler': ...]}
    (render/renderer.py).
  target: float32 [B, 3], the colours the rays should render. rays: the rays rendered (those of
  the corrected cameras with pose refinement). params: the trained parameters.
  weight: float32 [B] or None, each ray's weight in the colour loss (its image's
  Dataset.lossmult: mip-NeRF's area weighting; times its pixel's mask in whole-image and patch
  batches of masked data, 0 = a masked pixel: a term that reads `target` must weight by it);
  None = every ray alike.
  mask: float32 [B] or None, with masked data (Dataset.masks) each ray's pixel mask: 1 kept, 0
  masked (its weight is 0 and its target black; a term that takes statistics of the batch
  leaves it out of them: robust.py); None = data without masks.
  step: int32 [] or None, the step number (the train step's; None outside it).
  keypoint_outputs: the renderer's outputs (as `outputs`) of the step's R keypoint rays, or None
    when no term asks for them (`keypoint_rays`, module docstring).
  keypoints: train_batches.Keypoints [R] or None, those rays' keypoints: their images, the t
    at their points and how t scales with the depth.
  """
  outputs: dict
  target: jnp.ndarray
  rays: Any
  params: dict
  weight: Any = None
  mask: Any = None
  step: Any = None
  keypoint_outputs: Any = None
  keypoints: Any = None


# The render passes of the renderer's outputs (outputs['sampler'] is a sampler's, not a pass).
PASSES = ("coarse", "fine")


@dataclasses.dataclass(frozen=True)
class Context:
  """What a term's `build` may use besides its settings: the run's, built by the entry layer.

  ray_renderer: the training RayRenderer (render/renderer.py; its sampler's `unit_distance`).
  table_axes: ((parameter-name prefix, spatial axes), ...) of the field's lattice tables (the
    encoding family's, fields/registry.py).
  pose_refinement: whether the run refines the cameras (params['poses'] exists).
  patch_size: the side P of the batch's patches (config.train.batching='patches', or
    config.loss.robust.weight > 0: run/builders.batch_settings; a batch is patches of P x P
    pixels, each row-major, train_batches.py); 0 = the rays are no patches.
  """
  ray_renderer: Any
  table_axes: tuple = ()
  pose_refinement: bool = dataclasses.field(kw_only=True)  # the run's: no default
  patch_size: int = 0


@dataclasses.dataclass(frozen=True)
class Loss(components.Component):
  """A loss term's record, a term module's `LOSS` (components.Component).

  name: its config section (config.loss.<name>) and the namespace of its stats; the term it
    builds has the same `name`.
  settings: its frozen settings dataclass: the section's fields, defaults (components.section)
    and validation (__post_init__, a ValueError naming the config field).
  build: (settings, Context) -> the term (a callable on LossInputs with a `name`), or None when
    the settings turn it off (a weight of 0).
  signature: a term changes no parameter, so none by default.
  """
  signature: Callable[[Any], dict] = lambda settings: {}


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.loss's own field (each term's settings are its section, config.loss.<name>)."""
  terms: Tuple[str, ...] = ("colour", "distortion", "pose_prior", "total_variation", "transient",
                            "robust", "masked_empty", "depth")  # added in this order


def check_weight(weight, term, example):
  """A term's weight setting (config.loss.<term>.weight): ValueError naming the field unless
  it is >= 0 (0 = off). example: a weight that works, for the message."""
  if weight < 0:
    raise ValueError(f"config.loss.{term}.weight={weight}: use 0 (off) or a weight > 0 (e.g. "
                     f"{example})")


# The built-in terms, by the name config.loss.terms gives them.
REGISTRY = components.Registry("loss term", "config.loss.terms", "LOSS", "loss", {
    "colour": "nerf_jax.train.losses.colour",
    "distortion": "nerf_jax.train.losses.distortion",
    "pose_prior": "nerf_jax.train.losses.pose_prior",
    "total_variation": "nerf_jax.train.losses.total_variation",
    "transient": "nerf_jax.train.losses.transient",
    "robust": "nerf_jax.train.losses.robust",
    "masked_empty": "nerf_jax.train.losses.masked_empty",
    "depth": "nerf_jax.train.losses.depth",
})


def keypoint_rays(terms):
  """The keypoint rays a step draws for `terms`: the most any asks for (`keypoint_rays`), 0 =
  none."""
  return max((getattr(term, "keypoint_rays", 0) for term in terms), default=0)


def total(terms, inputs):
  """(loss float32 [], stats): the terms' losses added in order; stats holds 'loss' (the total)
  and each term's stats as '<term.name>/<stat>'. ValueError when two terms would log the same
  name (two terms of one name reporting the same stat)."""
  loss, stats = None, {}
  for term in terms:
    if not isinstance(getattr(term, "name", None), str):
      raise TypeError(f"loss term {term!r} has no name (str): the namespace of its stats")
    value, term_stats = term(inputs)
    loss = value if loss is None else loss + value
    for stat, stat_value in term_stats.items():
      key = f"{term.name}/{stat}"
      if key in stats:
        raise ValueError(f"loss terms clash: two terms named {term.name!r} both log {stat!r} "
                         f"({key}); give each term a name of its own")
      stats[key] = stat_value
  return loss, {"loss": loss, **stats}
