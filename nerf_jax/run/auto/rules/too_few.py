"""Too few cameras to characterise: configs/capture.py's defaults, nothing measured."""

from nerf_jax.run.auto import characterise
from nerf_jax.run.auto.rule import Rule


def decide(context):
  """({}, [line]) where the capture has fewer than characterise.MIN_CAMERAS cameras."""
  if context.decisions is not None:
    return {}, []
  return {}, [f"{len(context.dataset)} cameras are too few to characterise (< "
              f"{characterise.MIN_CAMERAS}): using configs/capture.py's defaults"]


RULE = Rule("too_few", decide, row="too few cameras",
            representation=lambda context: "capture" if context.decisions is None else None)
