"""Large objects: an object on a background from LARGE_IMAGES pixels a side takes
configs/detail.py, a smaller one fast.py (the background rule); it prints no line of its own,
the representation's line names the choice."""

from nerf_jax.run.auto.rule import Rule

# auto: object captures from this many pixels a side use configs/detail.py, smaller ones fast.py.
# detail.py won at the smallest size measured, the built-in scenes' 100 px (docs/regret.md: 300 s
# on one core, diffuse +4.25 dB; 60 s, exposure +7.10, crowd +3.21); below it, unmeasured.
LARGE_IMAGES = 100


def representation(context):
  """'detail' for an object on a background (not forward-facing) from LARGE_IMAGES pixels."""
  dataset = context.dataset
  if (context.found("background") and not context.found("forward")
      and max(dataset.height, dataset.width) >= LARGE_IMAGES):
    return "detail"
  return None


RULE = Rule("large_objects", lambda context: ({}, []), row="large objects",
            representation=representation)
