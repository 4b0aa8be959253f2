"""Forward-facing cameras (characterise's 'forward'): configs/llff.py, NDC rays."""

from nerf_jax.run.auto.rule import Rule, measured


@measured
def decide(context):
  """({'data.ndc': True, 'data.lindisp': False}, [line]) where the cameras face one way."""
  reason = context.reason("forward")
  if not context.found("forward"):
    return {}, [f"no forward: {reason}"]
  return ({"data.ndc": True, "data.lindisp": False},
          [f"forward-facing: NDC rays (data.ndc): {reason}"])


def flip_forward(result, base, context):
  """NDC rays off where auto turned them on."""
  if result.data.ndc:
    return {"data.ndc": False}, ""
  return None, "NDC rays need cameras that face one way (auto found none)"


RULE = Rule("forward", decide, row="forward-facing", fields=("data.ndc", "data.lindisp"),
            flips={"forward": flip_forward},
            # the winner on fern (docs/quality_per_second.md)
            representation=lambda context: "llff" if context.found("forward") else None)
