"""Highlights that move between views (characterise's 'view_dependence', measured where the
views have depth): colour from the viewing direction; else the representation's own setting."""

from nerf_jax.run.auto.rule import Rule, measured, switch_flip


@measured
def decide(context):
  """({'model.view_dependent': found}, [line]); ({}, [line]) where not measured."""
  found, reason = context.found("view_dependence"), context.reason("view_dependence")
  if found is None:  # the representation's own setting
    return {}, [f"view dependence {'on' if context.result.model.view_dependent else 'off'} as "
                f"in configs/{context.chosen}.py: {reason}"]
  return {"model.view_dependent": found}, [
      f"view dependence: colour from the viewing direction too (model.view_dependent): "
      f"{reason}" if found else f"no view dependence: {reason}"]


# The step rule (auto.MIN_STEPS): measured with detail.py on one core, side by side
# (docs/regret.md, the step rule), in the steps of the run with the effect off: view dependence
# on glossy loses 4.2 dB at 85 steps and 1.3 at 124, gains 0.5 at 180; the threshold: where the
# line between crosses.
RULE = Rule("view_dependence", decide, row="view dependence", fields=("model.view_dependent",),
            flips={"view_dependence": switch_flip("model.view_dependent")},
            min_steps={"model.view_dependent": (False, 165)})
