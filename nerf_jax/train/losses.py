"""The training loss as a list of terms, one pure function each.

A term is called as term(inputs) with a `LossInputs` and returns (loss: float32 [], stats: dict of
float32 or int32 [] scalars to log); the step adds the terms' losses in their order and logs every
stat they return. A component that needs a term of its own brings it (the entry layer lists the
terms of a run, run/experiment.py).
"""

import dataclasses
from typing import Any, Callable

import flax.struct
import jax
import jax.numpy as jnp

from nerf_jax.evaluate import metrics
from nerf_jax.fields import registry
from nerf_jax.render import renderer
from nerf_jax.train import regularizers


@flax.struct.dataclass
class LossInputs:
  """What a loss term may look at, for one batch of B rays.

  outputs: the renderer's outputs {'coarse': ..., ['fine': ...], ['sampler': ...]}
    (render/renderer.py).
  target: float32 [B, 3], the colours the rays should render. rays: the rays rendered (those of
  the corrected cameras with pose refinement). params: the trained parameters.
  """
  outputs: dict
  target: jnp.ndarray
  rays: Any
  params: dict


# The render passes of the renderer's outputs (outputs['sampler'] is a sampler's, not a pass).
PASSES = ("coarse", "fine")


def _mean_over_rays(per_channel, complete=None):
  """The mean of per_channel float32 [B, 3] over the rays with complete bool [B] (None: all
  rays). A sample budget always completes its first ray unless that ray alone has more valid
  samples than the budget: max(count, 1) keeps it finite."""
  if complete is None:
    return jnp.mean(per_channel)
  kept = jnp.where(complete[:, None], per_channel, 0.0)
  return jnp.sum(kept) / (3.0 * jnp.maximum(jnp.sum(complete), 1))


def _mse(rgb, target, complete=None):
  """Mean squared error of rgb float32 [B, 3] against target float32 [B, 3] (see
  `_mean_over_rays` for complete)."""
  return _mean_over_rays((rgb - target) ** 2, complete)


def huber(error, delta):
  """Huber's loss of error float32 [...] with knee delta > 0: error²/2 where |error| <= delta,
  delta·(|error| - delta/2) beyond (instant-ngp's colour loss, delta 0.1). Its gradient is the
  error clipped to ±delta: a few pixels far off (specks, edges the cameras disagree on) pull no
  harder than a pixel delta off. jnp.where selects: both branches are finite for finite error."""
  size = jnp.abs(error)
  return jnp.where(size <= delta, 0.5 * error ** 2, delta * (size - 0.5 * delta))


@dataclasses.dataclass(frozen=True)
class Colour:
  """The photometric loss: the mean squared error of the final pass, plus coarse_weight times
  the coarse pass's when there is a fine pass; with huber_delta > 0 the mean `huber` loss of
  each channel's error instead. With a sample budget only whole rays count.
  Stats: psnr of the final pass (from its squared error, whatever the loss); with a sample
  budget, rays_in_loss (the rays it held whole) and samples_wanted (the valid samples of every
  drawn ray: above the budget, rays were drawn in vain; below it, budget slots went empty)."""
  coarse_weight: float = 1.0
  huber_delta: float = 0.0

  def _pass_loss(self, rgb, target, complete):
    if self.huber_delta <= 0:
      return _mse(rgb, target, complete)
    return _mean_over_rays(huber(rgb - target, self.huber_delta), complete)

  def __call__(self, inputs):
    outs = inputs.outputs
    complete = outs["coarse"].get("complete")  # a sample budget: only whole rays count
    names = [name for name in PASSES if name in outs]
    per_pass = {name: self._pass_loss(outs[name]["rgb"], inputs.target, complete)
                for name in names}
    loss = per_pass["coarse"] if "fine" not in per_pass else (
        per_pass["fine"] + self.coarse_weight * per_pass["coarse"])
    mse = per_pass[names[-1]] if self.huber_delta <= 0 else _mse(
        outs[names[-1]]["rgb"], inputs.target, complete)
    stats = {"psnr": metrics.mse_to_psnr(mse)}
    if complete is not None:  # how many rays the budget held whole, and what all asked of it
      stats["rays_in_loss"] = jnp.sum(complete, dtype=jnp.int32)
      stats["samples_wanted"] = jnp.sum(outs["coarse"]["valid_samples"], dtype=jnp.int32)
    return loss, stats


@dataclasses.dataclass(frozen=True)
class Distortion:
  """mip-NeRF 360's distortion loss: each ray's weight kept in one place (no floaters).

  In normalised ray distance (mip-NeRF 360's s, `unit_distance(t, rays)`: the sampler's): the
  same weight at any scene scale, and finite for an unbounded scene's edges out to 1e10. It
  shapes the weights only: no gradient reaches the cameras (pose refinement) through the edges.
  """
  weight: float
  unit_distance: Callable

  def __call__(self, inputs):
    last = renderer.final(inputs.outputs)
    s = jax.lax.stop_gradient(self.unit_distance(last["t"], inputs.rays))
    return self.weight * jnp.mean(regularizers.distortion(s, last["weights"])), {}


@dataclasses.dataclass(frozen=True)
class PosePrior:
  """A zero-mean Gaussian prior on each camera's correction (rotation in radians, move in scene
  units): directions the images barely constrain stay near the given poses instead of drifting
  with the field's noise."""
  weight: float

  def __call__(self, inputs):
    return self.weight * jnp.mean(jnp.sum(inputs.params["poses"] ** 2, axis=-1)), {}


@dataclasses.dataclass(frozen=True)
class TotalVariation:
  """Smooth lattice tables where few rays constrain them (LLFF): the total variation of every
  lattice table of the field's encoding family (registry.Encoding.table_axes: parameter-name
  prefix -> spatial axes)."""
  weight: float
  table_axes: Any = ()

  def __call__(self, inputs):
    tables = registry.lattice_tables(inputs.params, dict(self.table_axes))
    return self.weight * sum(regularizers.total_variation(table, axes)
                             for table, axes in tables), {}


def total(terms, inputs):
  """(loss float32 [], stats): the terms' losses added in order, their stats merged; stats
  'loss' is the total."""
  loss, stats = None, {}
  for term in terms:
    value, term_stats = term(inputs)
    loss = value if loss is None else loss + value
    stats.update(term_stats)
  return loss, {"loss": loss, **stats}

