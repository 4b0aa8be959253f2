"""An object on a background (characterise's 'background'): random backgrounds while training,
configs/fast.py (detail.py from large_objects.LARGE_IMAGES); data.background is the data's."""

from nerf_jax.run.auto.rule import Rule, measured, switch_flip


@measured
def decide(context):
  """({field: value}, [line]): the data's background colour, random backgrounds where an object
  is on one (and the cameras do not face one way: NDC rays take the forward rule's config)."""
  bg = tuple(float(c) for c in context.dataset.background)
  effects = {"data.background": ("white" if bg == (1.0, 1.0, 1.0) else
                                 "black" if bg == (0.0, 0.0, 0.0) else bg)}
  if context.found("background") and not context.found("forward"):
    effects["train.random_background"] = True
  reason = context.reason("background")
  return effects, [f"an object on a background: a box, random backgrounds while training: "
                   f"{reason}" if context.found("background") else f"no background: {reason}"]


RULE = Rule("background", decide, row="background",
            fields=("data.background", "train.random_background"),
            flips={"background": switch_flip("train.random_background")},
            representation=lambda context: (
                "fast" if context.found("background") and not context.found("forward")
                else None))
