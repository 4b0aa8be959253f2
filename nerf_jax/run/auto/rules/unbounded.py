"""An unbounded capture (characterise's 'unbounded': no background, not forward-facing):
configs/capture.py, the box from the data (the contraction and focus rules read it)."""

from nerf_jax.run.auto.rule import Rule, measured


@measured
def decide(context):
  """({}, [line]): what the capture is; capture.py is the choice where no rule names one."""
  reason = context.reason("unbounded")
  return {}, [f"unbounded: the scene box from the data (data.scene_bound=-1): {reason}"
              if context.found("unbounded") else f"no unbounded: {reason}"]


RULE = Rule("unbounded", decide, row="unbounded")
