"""The user's flags win over the rules' decisions (auto.auto_config applies them last); a line
names each that differs from what auto decided."""

from nerf_jax.run.auto.rule import Rule


def decide(context):
  """({}, [line]) for each of the user's fields that differs from auto's effect."""
  lines = []
  for name, value in context.user.items():
    if name in context.effects and context.effects[name] != value:
      lines.append(f"{name}={value!r} from your flags, not auto's {context.effects[name]!r}")
  return {}, lines


RULE = Rule("your_flags", decide, row="your flags")
