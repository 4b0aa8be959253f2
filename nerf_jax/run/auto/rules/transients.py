"""Transients (passers-by) in a photo collection: RobustNeRF's trimmed loss, measured after a
short warm-up (warm_up.py, transient_share.py)."""

from nerf_jax.run.auto import transient_share, warm_up
from nerf_jax.run.auto.rule import Rule, measured

# Transients (passers-by): RobustNeRF's loss above this share of clustered outliers after the
# warm-up; crowd 0.027, the clean built-in scenes <= 0.0033 at 48 px (docs/photo_collections.md).
TRANSIENT_SHARE = 0.01


def transient_effects(dataset, collection, patch_size):
  """({field: value}, one line): RobustNeRF's trimmed loss (its switch, loss.robust.weight: the
  patch batches follow from it) when a warm-up on the photos of `dataset` (one camera) leaves
  more than TRANSIENT_SHARE of their pixels clustered outliers that some photos hold
  (transient_share.transient_share: passers-by). The patches are patch_size a side (the run's
  train.patch_size), train.patch_size set smaller only for photos smaller than that. Measured
  only for a photo collection (`collection`: the photos have their own looks, the appearance
  rule), as the warm-up costs half a minute on a CPU."""
  if not collection:
    return {}, ("no transients: not measured (the photos share one look: not a collection "
                "taken by many)")
  share = transient_share.transient_share(*warm_up.photos_and_renders(dataset))[0]
  reason = (f"{100 * share:.1f}% of the training pixels are clustered outliers specific to "
            f"some photos after a {warm_up.WARM_UP_STEPS}-step warm-up "
            f"({'>' if share > TRANSIENT_SHARE else '<='} {100 * TRANSIENT_SHARE:g}%)")
  if share <= TRANSIENT_SHARE:
    return {}, f"no transients: {reason}"
  effects = {"loss.robust.weight": 1.0}
  patch = int(min(patch_size, dataset.height, dataset.width))
  if patch < patch_size:  # a patch lies in one photo
    effects["train.patch_size"] = patch
  return (effects,
          f"transients left out: RobustNeRF's trimmed loss on {patch} x {patch} patches "
          f"(loss.robust): {reason}")


@measured
def decide(context):
  """transient_effects of the one-camera views of a collection (the appearance rule's)."""
  effects, line = transient_effects(
      context.dataset, context.found("appearance"),
      context.user.get("train.patch_size", context.result.train.patch_size))
  return effects, [line]


def flip_transients(result, base, context):
  """RobustNeRF's trimmed loss off, or on with patches that fit the images (one camera: the
  patch batches need it)."""
  if result.loss.robust.weight > 0:
    return {"loss.robust.weight": 0.0, "train.patch_size": int(base.train.patch_size)}, ""
  if not context["one_camera"]:
    return None, "its patch batches need images of one camera"
  patch = int(min(result.train.patch_size, context["height"], context["width"]))
  return {"loss.robust.weight": 1.0, "train.patch_size": patch}, ""


# The step rule (auto.MIN_STEPS): measured with detail.py on one core, side by side
# (docs/regret.md, the step rule), in the steps of the run with the effect off: the trimmed loss
# on crowd (its patch batches) loses 1.5 dB at 69 steps and gains 1.9 at 99; the threshold:
# where the line between crosses.
RULE = Rule("transients", decide, row="transients (trimmed loss)",
            fields=("loss.robust.weight",), flips={"transients": flip_transients},
            min_steps={"loss.robust.weight": (0.0, 80)})
