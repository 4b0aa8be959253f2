"""The runs of the regret benchmark (bench/regret.py): auto's config, auto's config with each of
its on/off decisions flipped alone, and the other representations auto could have chosen.

Names used throughout:
  result    the ConfigDict auto decided (auto.auto_config; auto off, auto_decisions its lines)
  chosen    the representation auto chose: its config name ('fast', 'capture', 'gpu/lego'...),
            config.auto_representation, set by auto
  overrides {dotted field: value}: a flip on top of `result`, or auto's effects and the
            command's fields on top of another representation's config

A flip is read from `result` itself: a switch auto left on is turned off and one it left off
is turned on (FLIPS: each rule's flips, Rule.flips, in the rules' order). A flip that would
not make sense for the data (NDC rays on cameras that do not face one way) is left out with one line saying why.
"""

import dataclasses

import ml_collections

from nerf_jax.run import config_lib
from nerf_jax.run.auto.rules import RULES, cones
from nerf_jax.run.auto.rules import backend as backend_rule

# The effects auto decides (its rules' Rule.fields); a representation run keeps auto's values of
# them.
EFFECT_FIELDS = tuple(field for rule in RULES for field in rule.fields)
# The representations auto chooses from (auto.auto_config) and configs/hash.py, the lattice
# it could take instead of fast.py's dense grids; on a GPU, backend.GPU_CONFIGS's counterparts.
REPRESENTATIONS = ("fast", "detail", "hash", "llff", "capture")
FORWARD_ONLY = ("llff",)  # grids in NDC: only for forward-facing cameras
NO_FORWARD = ("fast", "detail", "hash")  # a box around an object: not for NDC rays


@dataclasses.dataclass
class Run:
  """One planned run. name: 'auto', 'flip/<decision>' or 'config/<name>'. flipped: the
  decision flipped ('' for auto, 'representation' for another config). base: the config name
  the run starts from. overrides: {field: value} on top of it (see the module docstring).
  config: the ConfigDict the run trains (auto off)."""
  name: str
  flipped: str
  base: str
  overrides: dict
  config: ml_collections.ConfigDict


def chosen_config(result):
  """The config name auto chose (config.auto_representation); ValueError where `result` was
  not decided by auto."""
  chosen = result.get("auto_representation", "")
  if not chosen:
    raise ValueError("the config was not decided by auto (no auto_representation): regret "
                     "measures --config=auto")
  return chosen


# decision name -> rule.Flip (its rule's, Rule.flips), in the rules' order: flip(result, base,
# context) -> (overrides or None, why none). context: {'height', 'width': the training images'
# pixels, 'one_camera': whether they share one camera}.
FLIPS = {name: flip for rule in RULES for name, flip in rule.flips.items()}


def copy(config):
  """A fresh ConfigDict with the values of `config`."""
  return ml_collections.ConfigDict(config.to_dict())


def with_fields(config, overrides):
  """A copy of `config` with auto off and each dotted field of `overrides` set."""
  out = copy(config)
  out.auto = False
  for name, value in overrides.items():
    config_lib.set_field(out, name, value)
  return out


def flip_runs(result, chosen, height, width, one_camera=True):
  """([Run] of every decision FLIPS can flip on `result`, [line] for each it cannot).
  chosen: auto's config name; height, width: int, the training images' pixels (image 0's);
  one_camera: whether every training image shares one camera."""
  base = config_lib.load(chosen)
  context = {"height": height, "width": width, "one_camera": one_camera}
  runs, skipped = [], []
  for decision, flip in FLIPS.items():
    overrides, why = flip(result, base, context)
    if overrides is None:
      skipped.append(f"flip/{decision}: not run ({why})")
      continue
    config = with_fields(result, overrides)
    config.auto_decisions = ()
    # A flipped effect is the flip's, whatever the budget.
    config.auto_by_steps = tuple(f for f in config.auto_by_steps if f not in overrides)
    runs.append(Run(f"flip/{decision}", decision, chosen, overrides, config))
  return runs, skipped


def candidates(chosen, backend):
  """{config name: its CPU name in REPRESENTATIONS} of REPRESENTATIONS on `backend` ('cpu',
  'gpu'...; rules/backend.for_backend: 'fast' and 'detail' are both 'gpu/lego' there, named 'fast'),
  less `chosen`, in order."""
  names = {}
  for kind in REPRESENTATIONS:
    name = backend_rule.for_backend(kind, backend)[0] if kind in backend_rule.GPU_CONFIGS else kind
    names.setdefault(name, kind)
  return {name: kind for name, kind in names.items() if name != chosen}


def representation_runs(result, chosen, user, backend):
  """([Run] of each other representation that applies, [line] for each that does not).
  Each keeps auto's EFFECT_FIELDS (and its patch size under the trimmed loss, and its step
  rule: auto.by_steps), takes the
  cones cones.cone_effects gives it where `result` reads cones, and the command's `user`
  fields ({field: value}: data, budget) on top; its overrides are those that differ from the
  representation's own config."""
  forward = bool(result.data.ndc)
  runs, skipped = [], []
  for name, kind in candidates(chosen, backend).items():
    why = (kind in FORWARD_ONLY and not forward and "grids in NDC, for forward-facing cameras"
           or kind in NO_FORWARD and forward and "a box around an object: not for NDC rays")
    if why:
      skipped.append(f"config/{name}: not run ({why})")
      continue
    base = config_lib.load(name)
    overrides = {f: config_lib.get_field(result, f) for f in EFFECT_FIELDS}
    if result.loss.robust.weight > 0:
      overrides["train.patch_size"] = result.train.patch_size
    if cones.has_cones(result):
      overrides.update(cones.cone_effects(base))
    overrides.update(user)
    overrides["auto_by_steps"] = result.auto_by_steps  # auto's step rule, as in auto's run
    overrides = {f: v for f, v in overrides.items() if config_lib.get_field(base, f) != v}
    runs.append(Run(f"config/{name}", "representation", name, overrides,
                    with_fields(base, overrides)))
  return runs, skipped


def plan(result, user, height, width, backend, one_camera=True):
  """([Run]: auto's run first, then its flips, then the other representations; [line] for each
  run left out). result: auto's ConfigDict; user: {field: value} the command set; height,
  width: int, the training images' pixels (image 0's); backend: jax.default_backend();
  one_camera: whether every training image shares one camera."""
  chosen = chosen_config(result)
  runs = [Run("auto", "", chosen, {}, with_fields(result, {}))]
  flips, skipped = flip_runs(result, chosen, height, width, one_camera)
  others, left_out = representation_runs(result, chosen, user, backend)
  return runs + flips + others, skipped + left_out
