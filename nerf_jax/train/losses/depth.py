"""Depth from the sparse points' tracks (DS-NeRF, Deng et al. 2022: "Depth-supervised NeRF:
Fewer Views and Faster Training for Free"): config.loss.depth.

Structure from motion saw each sparse point in a few images: the ray through the point's
keypoint in each of them should end at the point. Each step renders `rays` such keypoint rays,
observations drawn at random over the training images (train_batches.Keypoints: the point
projected through its image's camera as trained, so every move of the world keeps it), and adds
the weight times, in every render pass, the mean over them of

  'kl'      DS-NeRF's KL form: sum_k -log(w_k + KL_EPS) · exp(-(t_k - D)² / (2 σ²)) · Δt_k
            over the ray's intervals (weights w_k, midpoints t_k, lengths Δt_k): the ray's
            weights pulled up near the point's depth D, and so down in front of it (the fog of
            few views);
  'robust'  Charbonnier's sqrt(1 + r²) - 1 of r = (E[t] - D) / σ, the expected depth's error in
            spreads: quadratic near D, linear (a bounded pull) far from it.

D and σ are in the ray's t: z-depth, or NDC's s. σ follows the point's reprojection error as
DS-NeRF weighs its points: σ = sigma · max(e / ē, min_error_ratio) · depth (in t: times
dt/d depth, Keypoints.scale), e the point's error, ē the mean over the points kept (a point
twice as uncertain as most gets twice the spread; the floor keeps the best points from a spread
too thin for the samples to resolve). Needs the data's
tracks (Dataset.observations: a COLMAP model, or one beside transforms.json or an LLFF folder).
"""

import dataclasses
from typing import ClassVar

import jax.numpy as jnp

from nerf_jax.render import renderer
from nerf_jax.train import losses

FORMS = ("kl", "robust")
KL_EPS = 1e-5  # -log(w + KL_EPS): finite where an interval holds no weight (DS-NeRF's 1e-5)


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.loss.depth."""
  weight: float = 0.0  # weight of the sparse points' depth on their keypoints' rays (0 = off)
  form: str = "kl"  # 'kl' (DS-NeRF: the weights near the point) or 'robust' (the expected depth)
  rays: int = 256  # keypoint rays a step renders: observations drawn over all training images
  sigma: float = 0.02  # depth spread of a point of mean reprojection error: a share of its depth
  min_error_ratio: float = 0.5  # the least error / mean error a point's spread is scaled by

  def __post_init__(self):
    losses.check_weight(self.weight, "depth", "0.1")
    if self.form not in FORMS:
      raise ValueError(f"config.loss.depth.form={self.form!r}: use one of {FORMS}")
    if self.rays < 1:
      raise ValueError(f"config.loss.depth.rays={self.rays}: a step renders at least one "
                       "keypoint ray (e.g. 256)")
    if not self.sigma > 0:
      raise ValueError(f"config.loss.depth.sigma={self.sigma}: the spread must be > 0 (e.g. "
                       "0.02, 2% of the depth)")
    if not self.min_error_ratio > 0:
      raise ValueError(f"config.loss.depth.min_error_ratio={self.min_error_ratio}: the floor "
                       "must be > 0 (e.g. 0.5), or a point of error 0 has no spread")


def spread(keypoints, sigma, min_error_ratio):
  """float32 [R]: σ of each of `keypoints` (train_batches.Keypoints [R]) in the ray's t (module
  docstring)."""
  return sigma * jnp.maximum(keypoints.error, min_error_ratio) * keypoints.scale


def kl(weights, t, target, sigma):
  """float32 [R]: DS-NeRF's KL form of each ray (module docstring).

  weights: float32 [R, E], the pass's weights over its intervals. t: float32 [R, E + 1], the
  intervals' edges. target, sigma: float32 [R], the point's t and its spread (> 0)."""
  mids, lengths = 0.5 * (t[:, 1:] + t[:, :-1]), t[:, 1:] - t[:, :-1]
  near_point = jnp.exp(-jnp.square(mids - target[:, None]) / (2.0 * jnp.square(sigma[:, None])))
  return jnp.sum(-jnp.log(weights + KL_EPS) * near_point * lengths, axis=-1)


def robust(depth, target, sigma):
  """float32 [R]: Charbonnier's sqrt(1 + r²) - 1 of r = (depth - target) / sigma (depth,
  target, sigma: float32 [R]; sigma > 0)."""
  return jnp.sqrt(1.0 + jnp.square((depth - target) / sigma)) - 1.0


@dataclasses.dataclass(frozen=True)
class Depth:
  """weight x the 'kl' or 'robust' loss (module docstring) of the step's keypoint rays, summed
  over the render passes (each the mean over its complete rays). Stats: the form's loss of the
  final pass ('kl' or 'robust') and 'error', the mean |E[t] - D| / depth · dt/d depth: the
  rendered depth's error as a share of the point's depth."""
  name: ClassVar[str] = "depth"
  weight: float
  form: str
  keypoint_rays: int
  sigma: float
  min_error_ratio: float

  def __call__(self, inputs):
    keypoints = inputs.keypoints
    sigma = spread(keypoints, self.sigma, self.min_error_ratio)
    total, per_pass = 0.0, {}
    for name in losses.PASSES:
      out = inputs.keypoint_outputs.get(name)
      if out is None:
        continue
      per_ray = (kl(out["weights"], out["t"], keypoints.t, sigma) if self.form == "kl" else
                 robust(out["depth"], keypoints.t, sigma))
      per_pass[name] = _mean(per_ray, out.get("complete"))
      total = total + per_pass[name]
    last = renderer.final(inputs.keypoint_outputs)
    error = _mean(jnp.abs(last["depth"] - keypoints.t) / keypoints.scale, last.get("complete"))
    final = per_pass["fine" if "fine" in per_pass else "coarse"]
    return self.weight * total, {self.form: final, "error": error}


def _mean(values, complete):
  """The mean of float32 [R] over the rays whose samples are whole (complete: bool [R], a
  sample budget's, or None = all)."""
  if complete is None:
    return jnp.mean(values)
  count = jnp.sum(complete.astype(jnp.float32))
  # At least one ray counted: a batch whose budget ran out before them gives 0, not 0 / 0.
  return jnp.sum(jnp.where(complete, values, 0.0)) / jnp.maximum(count, 1.0)


def build(settings, context):
  """The term; None at weight 0."""
  del context
  if settings.weight <= 0:
    return None
  return Depth(settings.weight, settings.form, settings.rays, settings.sigma,
               settings.min_error_ratio)


LOSS = losses.Loss(Depth.name, Settings, build)
