"""The box of an unbounded capture: where the chosen config takes it from the data without
contracting, the space beyond is contracted if too many training rays leave it."""

from nerf_jax.run import from_data
from nerf_jax.run.auto.rule import Rule

CONTRACTION = "linf"  # where the rays leave the box: nerfacto's contraction (docs/real_captures.md)


def decide(context):
  """({field: value}, [line]): for an unbounded capture whose config (the chosen one, with the
  user's flags) takes the box from the data without contracting, the share of training rays
  that leave that box (from_data.cut_share, the share the run's warning reads; on the user's
  data.scene_bound where they set one) decides: above from_data.CUT_SHARE the space beyond is
  contracted (data.contraction=CONTRACTION), so the warning never contradicts auto (a
  data.contraction of the user's is theirs: not measured). ({}, []) elsewhere."""
  if not context.found("unbounded"):
    return {}, []
  result, dataset, user = context.result, context.dataset, context.user
  contraction = user.get("data.contraction", result.data.contraction)
  bound = user.get("data.scene_bound", result.data.scene_bound)
  if contraction or "data.contraction" in user or not (bound == -1 or bound > 0):
    return {}, []
  if bound == -1:
    bound, why = from_data.scene_box("", dataset)
  else:
    why = "data.scene_bound"
  near, far = (user.get(f"data.{k}", 0.0) or getattr(dataset, k) for k in ("near", "far"))
  pixel_center = user.get("data.pixel_center", -1.0)
  pixel_center = dataset.pixel_center if pixel_center == -1 else pixel_center
  share = from_data.cut_share(dataset, bound, near, far, pixel_center)
  if share is None:
    return {}, []
  cut = share > from_data.CUT_SHARE
  measured = (f"{100 * share:.0f}% of the training rays leave the box ±{bound:.3g} from "
              f"{why} before their far bound {far:.3g} ({'>' if cut else '<='} "
              f"{100 * from_data.CUT_SHARE:.0f}%)")
  if cut:
    return {"data.contraction": CONTRACTION}, [
        f"the space beyond the box contracted (data.contraction={CONTRACTION!r}): {measured}"]
  return {}, [f"no contraction: {measured}"]


def flip_contraction(result, base, context):
  if result.data.ndc:
    return None, "NDC rays take no contraction"
  return {"data.contraction": "" if result.data.contraction else CONTRACTION}, ""


RULE = Rule("contraction", decide, row="contraction", fields=("data.contraction",),
            flips={"contraction": flip_contraction})
