"""Cameras at several scales (characterise's 'scales'): the chosen representation reads cones
(docs/multiscale.md)."""

from nerf_jax.run.auto.rule import Rule, measured

# Zip-NeRF's multisampling with its level weights, or the weights alone (multisample False):
# on the multiscale lego at 10 CPU-minutes the weights alone score best (docs/multiscale.md).
ANTIALIAS_MULTISAMPLE = False


def cone_effects(config):
  """{field: value} that make the representation `config` read cones (docs/multiscale.md): the
  integrated positional encoding for 'posenc', Zip-NeRF's anti-aliasing for a lattice (its
  multisampling as ANTIALIAS_MULTISAMPLE says). Rendering keeps the representation's marching,
  which queries each sample's frustum as the plain path does. {} for an encoding without cones
  (TensoRF)."""
  encoding = config.model.encoding
  if encoding == "posenc":
    return {"model.encoding": "ipe"}
  if encoding in ("grid", "hash"):
    return {f"model.{encoding}.antialias": True,
            f"model.{encoding}.multisample": ANTIALIAS_MULTISAMPLE}
  return {}


def cone_summary(config):
  """One phrase naming what `cone_effects` switches on for `config`."""
  effects = cone_effects(config)
  if not effects:
    return f"but model.encoding={config.model.encoding!r} has no anti-aliased form yet"
  return ", ".join(f"{k}={v!r}" for k, v in effects.items())


def has_cones(config):
  """Whether `config` reads cones: the integrated positional encoding, or a lattice's
  anti-aliasing (cone_effects)."""
  encoding = config.model.encoding
  return encoding == "ipe" or (encoding in ("grid", "hash") and
                               bool(config.model[encoding].antialias))


@measured
def decide(context):
  """(cone_effects of the chosen config where the cameras are at several scales, [line])."""
  reason = context.reason("scales")
  if not context.found("scales"):
    return {}, [f"one scale: {reason}"]
  return cone_effects(context.result), [
      "cameras at several scales: cones, " + cone_summary(context.result) + f": {reason}"]


def flip_cones(result, base, context):
  """Cones off (the representation's own encoding), or on as cone_effects turns them on."""
  if has_cones(result):
    return ({"model.encoding": "posenc"} if result.model.encoding == "ipe" else
            {f"model.{result.model.encoding}.antialias": False}), ""
  effects = cone_effects(result)
  if not effects:
    return None, f"model.encoding={result.model.encoding!r} has no cones yet"
  return effects, ""


RULE = Rule("cones", decide, row="cones (anti-aliasing)", flips={"cones": flip_cones})
