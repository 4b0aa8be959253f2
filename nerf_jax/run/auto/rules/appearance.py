"""Per-photo looks (characterise's 'appearance'): appearance codes, held-out photos scored the
NeRF-W way; a photo collection for the subject and transients rules."""

from nerf_jax.run.auto.rule import Rule, measured

APPEARANCE_DIMS = 8  # the appearance codes' length auto switches on (NeRF-W: 48, nerfacto: 32)


@measured
def decide(context):
  """({'model.appearance_dims': APPEARANCE_DIMS or 0, ...}, [line])."""
  found, reason = context.found("appearance"), context.reason("appearance")
  effects = {"model.appearance_dims": APPEARANCE_DIMS if found else 0}
  if found:  # held-out photos scored as NeRF-W scores them
    effects["eval.appearance"] = "left_half"
  return effects, [f"per-photo appearance codes (model.appearance_dims={APPEARANCE_DIMS}), "
                   f"held-out photos scored with a code fitted on their left half "
                   f"(eval.appearance='left_half'): {reason}" if found else
                   f"no appearance: {reason}"]


def flip_appearance(result, base, context):
  return {"model.appearance_dims": 0 if result.model.appearance_dims else APPEARANCE_DIMS}, ""


RULE = Rule("appearance", decide, row="appearance codes",
            fields=("model.appearance_dims", "eval.appearance"),
            flips={"appearance": flip_appearance})
