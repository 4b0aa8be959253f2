"""RobustNeRF's trimmed photometric loss (Sabour et al. 2023; config.loss.robust, off at weight
0): the pixels whose colour the static scene cannot explain (a passer-by, a car) are left out
of the loss, so that they neither pull the field nor leave floaters.

config.loss.robust.weight > 0 is the one switch; what it needs follows from it:
  * the batches are patches of config.train.patch_size (`batching`): n patches of P x P
    pixels, patch after patch, each row-major; config.train.batching='images' contradicts it
    (a ValueError naming both fields), 'rays' (the default) or 'patches' give patches;
  * it is the photometric loss of every ray of the batch: the colour term steps aside (the
    entry layer builds it with weight 0, whatever config.loss.colour.weight says: it reports
    its PSNR only), so the two are never added (`Robust.replaces_colour`).

A pixel's residual is its squared colour error, averaged over the channels. On a batch of
patches a pixel is kept (an inlier, weight 1) when any of these holds, else left out:
  * its residual is below the `inlier_quantile` of the batch's residuals;
  * more than `neighbour_share` of the filter_size x filter_size box around it (zeros beyond the
    patch's edge) are such pixels: a lone outlier among inliers is fine detail, not an object;
  * it lies in the middle inner_size x inner_size square of a patch of which more than
    `patch_share` of the pixels are such pixels (with `dilate`, RobustNeRF's code: pixels kept
    by either rule above; without it, the default, pixels kept by the first alone).
What is left out is a cluster of large residuals, the shape of an object. The mask is not
differentiated (the threshold and the weights are constants of the step, as in RobustNeRF).
The loss is the mean residual over the kept pixels (their trimmed mean), of every render pass
added (each pass weighs 1: the colour term's coarse_weight is not applied); with per-ray
weights (LossInputs.weight) the weighted mean (a sample budget's incomplete rays are not left
out: use it without one).

Masked pixels (LossInputs.mask 0: Dataset.masks; weight 0 and a black target) enter no
statistic: the quantile is over the batch's unmasked pixels alone, a box's share of inliers is
over its unmasked pixels (and the cells beyond the patch's edge), a patch's vote over its
unmasked pixels, and the loss over the unmasked inliers. Without masks (mask None, or none 0)
the rule is the one above, bit for bit.

Warm-up (`warmup_steps` > 0, LossInputs.step): before step warmup_steps nothing is trimmed, the
loss is the mean residual over every unmasked pixel (the plain squared colour error, each pass
weighing 1); the trimming starts at step warmup_steps.
"""

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from nerf_jax.train import losses


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.loss.robust."""
  weight: float = 0.0  # the switch (0 = off); > 0: patches of train.patch_size, no colour loss
  inlier_quantile: float = 0.8  # inliers: below this quantile of the batch's residuals
  filter_size: int = 3  # side of the box around a pixel whose inliers can keep it
  neighbour_share: float = 0.5  # kept: more than this share of its box is inliers
  inner_size: int = 8  # side of each patch's middle square, kept whole for an inlier patch
  patch_share: float = 0.6  # an inlier patch: more than this share of its pixels is inliers
  dilate: bool = False  # the patch vote on the inliers dilated by the box rule (RobustNeRF's code)
  warmup_steps: int = 0  # steps of the plain loss (nothing trimmed) before the trimming starts

  def __post_init__(self):
    losses.check_weight(self.weight, "robust", "1.0")
    if not 0 < self.inlier_quantile <= 1:
      raise ValueError(f"config.loss.robust.inlier_quantile={self.inlier_quantile}: use a "
                       "share in (0, 1] (RobustNeRF: 0.8)")
    if self.filter_size < 1 or self.filter_size % 2 == 0:
      raise ValueError(f"config.loss.robust.filter_size={self.filter_size}: use an odd side "
                       "(RobustNeRF: 3)")
    if self.warmup_steps < 0:
      raise ValueError(f"config.loss.robust.warmup_steps={self.warmup_steps}: use 0 (trim from "
                       "the first step) or a number of steps of the plain loss first")


def batching(train_batching, weight):
  """The batching of a run whose config.train.batching is `train_batching` ('rays', 'images'
  or 'patches') and whose config.loss.robust.weight is `weight`: 'patches' when the trimmed
  loss is on (it looks at a pixel's neighbours), else `train_batching` itself. ValueError
  naming both fields for 'images' with the loss on (whole images are no patches)."""
  if weight <= 0:
    return train_batching
  if train_batching == "images":
    raise ValueError(f"config.train.batching={train_batching!r} contradicts "
                     f"config.loss.robust.weight={weight}: RobustNeRF's trimmed loss trains on "
                     "patches of config.train.patch_size; leave config.train.batching at "
                     "'rays' (or 'patches'), or set config.loss.robust.weight=0")
  return "patches"


def box_sum(x, size):
  """The sum of x float32 [n, P, P] over the size x size box (odd size) centred on each pixel,
  zeros beyond each patch's edge (RobustNeRF's 'SAME' convolution): float32 [n, P, P]."""
  return jax.lax.reduce_window(x, 0.0, jax.lax.add, (1, size, size), (1, 1, 1), "SAME")


def box_mean(x, size):
  """`box_sum` over the box's size * size cells: float32 [n, P, P]."""
  return box_sum(x, size) / (size * size)


def inner_square(patch, inner):
  """bool [P, P]: the middle inner x inner square of a P x P patch (all of it when inner >=
  P), placed as RobustNeRF does (the lower margin (P - inner) // 2)."""
  inner = min(inner, patch)
  lower = (patch - inner) // 2
  index = jnp.arange(patch)
  side = (index >= lower) & (index < lower + inner)
  return side[:, None] & side[None, :]


def inlier_mask(residual, settings, kept=None):
  """RobustNeRF's inlier mask of residual float32 [n, P, P] (each pixel's squared error,
  averaged over channels) under `settings` (Settings): (mask bool [n, P, P], threshold
  float32 [], the inlier_quantile of the residuals). kept: bool [n, P, P] or None, the
  unmasked pixels (None: all): a masked pixel enters no statistic (module docstring) and is
  never in the mask."""
  if kept is None:
    threshold = jnp.quantile(residual, settings.inlier_quantile)
  else:  # the quantile of the unmasked residuals alone (NaN sorts last and is not counted)
    threshold = jnp.nanquantile(jnp.where(kept, residual, jnp.nan), settings.inlier_quantile)
    # No unmasked pixel has no quantile (NaN): 0 keeps the logged threshold finite.
    threshold = jnp.where(jnp.any(kept), threshold, 0.0)
  inlier = residual < threshold
  if settings.inlier_quantile >= 1:  # the largest residual is below no quantile: keep all
    inlier = jnp.ones_like(inlier)
  if kept is not None:
    inlier = inlier & kept
  size = settings.filter_size
  neighbours = box_mean(inlier.astype(jnp.float32), size)
  near_inliers = neighbours > settings.neighbour_share
  if kept is not None:  # the share of the box's unmasked pixels and cells beyond the edge
    masked = box_sum((~kept).astype(jnp.float32), size)
    # count > share · cells, not count / cells > share: a GPU's approximate division can put
    # 3 / 6 above 0.5; where no cell is masked, the rule above, bit for bit.
    near_inliers = jnp.where(masked > 0, box_sum(inlier.astype(jnp.float32), size)
                             > settings.neighbour_share * (size * size - masked), near_inliers)
  voters = inlier | near_inliers if settings.dilate else inlier
  patch_inlier = jnp.mean(voters, axis=(1, 2), keepdims=True) > settings.patch_share
  if kept is not None:  # the share of the patch's unmasked pixels (none: no vote)
    count = jnp.sum(kept, axis=(1, 2), keepdims=True)
    votes = jnp.sum(voters & kept, axis=(1, 2), keepdims=True)
    patch_inlier = jnp.where(count < kept[0].size, votes > settings.patch_share * count,
                             patch_inlier)
  middle = inner_square(residual.shape[-1], settings.inner_size)[None] & patch_inlier
  mask = inlier | near_inliers | middle
  return (mask if kept is None else mask & kept), threshold


@dataclasses.dataclass(frozen=True)
class Robust:
  """The trimmed loss of a batch of n patches of patch_size² pixels (`inlier_mask`), times
  `weight`. Stats: inliers (the share of the unmasked pixels kept, final pass), threshold (the
  residual quantile, final pass). It replaces the colour term's loss (`replaces_colour`: the
  entry layer builds that term with weight 0 beside it)."""
  name: ClassVar[str] = "robust"
  replaces_colour: ClassVar[bool] = True
  weight: float
  patch_size: int
  settings: Settings

  def _pass_loss(self, rgb, target, ray_weight, kept, warm):
    residual = jnp.mean((rgb - target) ** 2, axis=-1)  # [B]
    patches = jax.lax.stop_gradient(residual).reshape(-1, self.patch_size, self.patch_size)
    mask, threshold = inlier_mask(patches, self.settings, kept)
    mask = mask.reshape(-1)
    if warm is not None:  # the warm-up: every unmasked pixel, nothing trimmed
      mask = jnp.where(warm, True if kept is None else kept.reshape(-1), mask)
    keep = mask.astype(jnp.float32)
    if ray_weight is not None:
      keep = keep * ray_weight
    # max(.., 1e-12): a batch whose pixels all have weight 0 keeps the loss finite (0).
    loss = jnp.sum(keep * residual) / jnp.maximum(jnp.sum(keep), 1e-12)
    if kept is None:
      share = jnp.mean(mask.astype(jnp.float32))
    else:
      share = jnp.sum(mask) / jnp.maximum(jnp.sum(kept), 1)
    return loss, share, threshold

  def __call__(self, inputs):
    outs = inputs.outputs
    names = [name for name in losses.PASSES if name in outs]
    kept = None
    if inputs.mask is not None:
      kept = (inputs.mask > 0).reshape(-1, self.patch_size, self.patch_size)
    warm = None
    if self.settings.warmup_steps > 0:
      if inputs.step is None:
        raise ValueError("config.loss.robust.warmup_steps > 0 needs the step number "
                         "(LossInputs.step)")
      warm = inputs.step < self.settings.warmup_steps
    total, share, threshold = 0.0, None, None
    for name in names:
      loss, share, threshold = self._pass_loss(outs[name]["rgb"], inputs.target, inputs.weight,
                                               kept, warm)
      total = total + loss
    return self.weight * total, {"inliers": share, "threshold": threshold}


def build(settings, context):
  """The term on the run's patches (context.patch_size: the entry layer draws patches whenever
  the weight is > 0, `batching`); None at weight 0. ValueError unless the batches are
  patches."""
  if settings.weight <= 0:
    return None
  if not context.patch_size:
    raise ValueError("config.loss.robust.weight > 0 needs patches of pixels (of "
                     "config.train.patch_size, e.g. 16): the batches here are none")
  return Robust(settings.weight, context.patch_size, settings)


LOSS = losses.Loss(Robust.name, Settings, build)
