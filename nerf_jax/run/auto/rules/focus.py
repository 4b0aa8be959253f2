"""Where an unbounded capture's space beyond the box is contracted and the cameras look at one
point (characterise.focus), the world is centred there."""

from nerf_jax.run.auto import characterise
from nerf_jax.run.auto.rule import Rule


def decide(context):
  """({'data.focus': found}, [line]) for an unbounded capture contracted (by the contraction
  rule, the user or the chosen config): the inner region sized from the sparse points' box
  where the data has one, else from the cameras' distances (from_data.scene_box)."""
  if not context.found("unbounded"):
    return {}, []
  contraction = context.effects.get("data.contraction") or context.user.get(
      "data.contraction", context.result.data.contraction)
  if not contraction:
    return {}, []
  dataset = context.dataset
  focus = characterise.focus(dataset.poses)
  size = ("the sparse points' box (core)" if dataset.core is not None else
          "the cameras' distances from it")
  return {"data.focus": focus.found}, [
      f"the inner region centred where the cameras look (data.focus), sized from "
      f"{size}: {focus.reason}" if focus.found else
      f"the inner region centred on the data's origin: {focus.reason}"]


def flip_focus(result, base, context):
  if not result.data.contraction:
    return None, "the world is centred only where the space beyond is contracted"
  return {"data.focus": not result.data.focus}, ""


RULE = Rule("focus", decide, row="focus", fields=("data.focus",), flips={"focus": flip_focus})
