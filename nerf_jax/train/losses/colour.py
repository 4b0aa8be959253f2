"""The photometric loss (config.loss.colour; always built): the final pass's colour error, plus a
weighted coarse pass's; squared error or Huber's loss; with a sample budget only whole rays
count. Beside a term that replaces it (`replaces_colour`: RobustNeRF's trimmed loss, on at
config.loss.robust.weight > 0) the entry layer builds it with weight 0: its PSNR only."""

import dataclasses
from typing import ClassVar

import jax.numpy as jnp

from nerf_jax.evaluate import metrics
from nerf_jax.train import losses


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.loss.colour."""
  weight: float = 1.0  # weight of the loss (0: its PSNR only; loss.robust on: 0 whatever it says)
  coarse_weight: float = 1.0  # weight of the coarse pass's loss when a fine pass exists
  huber_delta: float = 0.0  # Huber's loss, quadratic below this error (0 = squared error)

  def __post_init__(self):
    losses.check_weight(self.weight, "colour", "1.0")
    if self.huber_delta < 0:
      raise ValueError(f"config.loss.colour.huber_delta={self.huber_delta}: use 0 (squared "
                       "error) or the colour error below which Huber's loss is quadratic "
                       "(instant-ngp: 0.1)")


def mean_over_rays(per_channel, complete=None, weight=None):
  """The mean of per_channel float32 [B, 3] over the rays with complete bool [B] (None: all
  rays). A sample budget always completes its first ray unless that ray alone has more valid
  samples than the budget: max(count, 1) keeps it finite. weight: float32 [B] or None, each
  ray's weight (mip-NeRF's lossmult): the weighted mean sum(w·e) / sum(w) over the kept rays."""
  if weight is not None:
    if complete is not None:
      weight = jnp.where(complete, weight, 0.0)
    return jnp.sum(weight[:, None] * per_channel) / (3.0 * jnp.maximum(jnp.sum(weight),
                                                                       1e-12))
  if complete is None:
    return jnp.mean(per_channel)
  kept = jnp.where(complete[:, None], per_channel, 0.0)
  return jnp.sum(kept) / (3.0 * jnp.maximum(jnp.sum(complete), 1))


def mse(rgb, target, complete=None, weight=None):
  """Mean squared error of rgb float32 [B, 3] against target float32 [B, 3] (see
  `mean_over_rays` for complete and weight)."""
  return mean_over_rays((rgb - target) ** 2, complete, weight)


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
  each channel's error instead. With a sample budget only whole rays count. With per-ray
  weights (LossInputs.weight, the data's lossmult) every mean is the weighted mean. All of it
  times `weight` (0: another term, e.g. robust.py's, is the photometric loss; the stats stay).
  A term that replaces it has `replaces_colour` True (run/builders.loss_terms then builds
  this one with weight 0).
  Stats: psnr of the final pass (from its squared error, whatever the loss); with a sample
  budget, rays_in_loss (the rays it held whole) and samples_wanted (the valid samples of every
  drawn ray: above the budget, rays were drawn in vain; below it, budget slots went empty);
  with masked data (LossInputs.mask), masked_share (the share of the batch's rays that are
  masked pixels: 0 with random rays, drawn from the kept pixels alone).
  A pass with the transient head (its output has 'beta') is left to losses/transient.py."""
  name: ClassVar[str] = "colour"
  coarse_weight: float = Settings.coarse_weight  # defaults: the settings' (declared once)
  huber_delta: float = Settings.huber_delta
  weight: float = Settings.weight

  def _pass_loss(self, rgb, target, complete, weight):
    if self.huber_delta <= 0:
      return mse(rgb, target, complete, weight)
    return mean_over_rays(huber(rgb - target, self.huber_delta), complete, weight)

  def __call__(self, inputs):
    outs = inputs.outputs
    complete = outs["coarse"].get("complete")  # a sample budget: only whole rays count
    names = [name for name in losses.PASSES if name in outs]
    weight = inputs.weight  # per-ray lossmult and masks (0: masked), where the data has them
    per_pass = {name: self._pass_loss(outs[name]["rgb"], inputs.target, complete, weight)
                for name in names}
    loss = per_pass["coarse"] if "fine" not in per_pass else (
        per_pass["fine"] + self.coarse_weight * per_pass["coarse"])
    if "beta" in outs[names[-1]]:  # the transient head's pass: losses/transient.py scores it
      loss = (self.coarse_weight * per_pass["coarse"] if "fine" in per_pass
              else jnp.zeros((), jnp.float32))
    final_mse = per_pass[names[-1]] if self.huber_delta <= 0 else mse(
        outs[names[-1]]["rgb"], inputs.target, complete, weight)
    stats = {"psnr": metrics.mse_to_psnr(final_mse)}
    if complete is not None:  # how many rays the budget held whole, and what all asked of it
      stats["rays_in_loss"] = jnp.sum(complete, dtype=jnp.int32)
      stats["samples_wanted"] = jnp.sum(outs["coarse"]["valid_samples"], dtype=jnp.int32)
    if inputs.mask is not None:  # masked pixels in the batch (whole images, patches)
      stats["masked_share"] = jnp.mean((inputs.mask <= 0).astype(jnp.float32))
    return self.weight * loss, stats


def build(settings, context):
  """The term of `settings` (always on; context unused)."""
  del context
  return Colour(settings.coarse_weight, settings.huber_delta, settings.weight)


LOSS = losses.Loss(Colour.name, Settings, build)
