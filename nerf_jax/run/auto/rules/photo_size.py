"""The photos' size (data.factor): decided before the photos are read (resolution.py), from their
files' headers; its lines come first."""

from nerf_jax.run.auto.rule import Rule


def decide(context):
  """({'data.factor': f}, [line]) as resolution.factor_effects decided it before loading."""
  effects, lines = context.before_loading
  return dict(effects), list(lines)


RULE = Rule("photo_size", decide, row="photos' size", fields=("data.factor",))
