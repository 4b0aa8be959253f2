"""NeRF-W's loss of the pass that carries the transient head (config.loss.transient; NeRF-W
eq. 13): each ray's colour error scaled by its rendered uncertainty, the uncertainty's log, and
the transient density's mean. In config.loss.terms by default and on whenever
config.model.transient.dims > 0 (the entry layer adds it to a list that lacks it); the colour
term leaves that pass to it (losses/colour.py).

Per ray, with C the target and Ĉ, beta the pass's rgb and beta (render/compositing.
composite_with_transient) and sigma_tau its transient density at the ray's S samples:

  L = ||C - Ĉ||² / (2·beta²) + log(beta²) / 2 + density_weight · mean_k sigma_tau_k

averaged over the batch's rays (weighted by the data's lossmult where it has one). NeRF-W's
code adds 3 to keep the log positive; a constant changes no gradient, so it is left out.
"""

import dataclasses
from typing import ClassVar

import jax.numpy as jnp

from nerf_jax.evaluate import metrics
from nerf_jax.train import losses


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.loss.transient (NeRF-W's transient head, config.model.transient)."""
  weight: float = 1.0  # weight of the whole term (the uncertainty-scaled colour loss)
  density_weight: float = 0.01  # lambda_u: the transient density's mean (NeRF-W: 0.01)

  def __post_init__(self):
    losses.check_weight(self.weight, "transient", "1.0")
    if self.density_weight < 0:
      raise ValueError(f"config.loss.transient.density_weight={self.density_weight}: use a "
                       "weight >= 0 (NeRF-W: 0.01)")


def per_ray(rgb, target, beta, transient_density, density_weight):
  """NeRF-W's loss of each ray: float32 [B].

  rgb, target: float32 [B, 3]. beta: float32 [B], the rendered uncertainty, >= beta_min > 0
  (compositing adds beta_min): 1/beta² is at most 1/beta_min² (1111 at 0.03) and log(beta²)
  finite, so neither the value nor the gradient can blow up where the head renders no
  uncertainty. transient_density: float32 [B, S] >= 0. density_weight: lambda_u."""
  squared = jnp.sum((rgb - target) ** 2, axis=-1)
  return (squared / (2.0 * beta ** 2) + jnp.log(beta)
          + density_weight * jnp.mean(transient_density, axis=-1))


@dataclasses.dataclass(frozen=True)
class Transient:
  """The term: `weight` times the mean of `per_ray` over the pass that has 'beta' (the final
  one of training rays). Stats: beta (the mean rendered uncertainty), transient_density (its
  mean) and psnr of the static-plus-transient colour. Nothing without such a pass."""
  name: ClassVar[str] = "transient"
  weight: float = Settings.weight  # defaults: the settings' (declared once)
  density_weight: float = Settings.density_weight

  def __call__(self, inputs):
    passes = [inputs.outputs[n] for n in losses.PASSES
              if n in inputs.outputs and "beta" in inputs.outputs[n]]
    if not passes:
      return jnp.zeros((), jnp.float32), {}
    out = passes[-1]
    loss = per_ray(out["rgb"], inputs.target, out["beta"], out["transient_density"],
                   self.density_weight)
    weight = inputs.weight
    mean = jnp.mean(loss) if weight is None else jnp.sum(weight * loss) / jnp.maximum(
        jnp.sum(weight), 1e-12)  # a weight sum of 0 (no ray counts): 0, not 0/0
    stats = {"beta": jnp.mean(out["beta"]),
             "transient_density": jnp.mean(out["transient_density"]),
             "psnr": metrics.mse_to_psnr(jnp.mean((out["rgb"] - inputs.target) ** 2))}
    return self.weight * mean, stats


def build(settings, context):
  """The term, where the training renderer has a transient head (else None: off)."""
  if getattr(context.ray_renderer, "transient", None) is None:
    return None
  if settings.weight <= 0:
    raise ValueError("config.loss.transient.weight=0 with config.model.transient.dims > 0: "
                     "the transient pass would have no loss; use a weight > 0 (e.g. 1.0)")
  return Transient(settings.weight, settings.density_weight)


LOSS = losses.Loss(Transient.name, Settings, build)
