"""The step rule: the effects that pay only after enough steps (the rules' min_steps, gathered in
auto.MIN_STEPS) wait until the run knows its step budget (auto.by_steps decides them)."""

from nerf_jax.run.auto.rule import Rule


def decide(context):
  """({'auto_by_steps': the waiting fields}, [line]) where an effect auto turned on (not one of
  the user's flags) pays only from a step count; ({}, []) where none does."""
  effects, user = context.effects, context.user
  pending = tuple(f for f, (off, _) in context.min_steps.items()
                  if f in effects and f not in user and effects[f] != off)
  if not pending:
    return {}, []
  return {"auto_by_steps": pending}, [
      f"step rule: {', '.join(pending)} kept only where the run's step budget holds the steps "
      "from which they pay (auto.MIN_STEPS), decided once the budget is known"]


def flip_step_rule(result, base, context):
  """Auto's step rule off (auto.by_steps): the effects it waits to decide stay on at any
  budget."""
  if not result.auto_by_steps:
    return None, "auto turned on nothing that pays only from a step count (auto.MIN_STEPS)"
  return {"auto_by_steps": ()}, ""


RULE = Rule("step_rule", decide, row="step rule", flips={"step_rule": flip_step_rule})
