"""The runs of the regret benchmark (bench/regret.py): auto's config, auto's config with each of
its on/off decisions flipped alone, and the other representations auto could have chosen.

Names used throughout:
  result    the ConfigDict auto decided (auto.auto_config; auto off, auto_decisions its lines)
  chosen    the representation auto chose: its config name ('fast', 'capture', 'gpu/lego'...),
            read from auto's last line, 'representation: configs/NAME.py'
  overrides {dotted field: value}: a flip on top of `result`, or auto's effects and the
            command's fields on top of another representation's config

A flip is read from `result` itself: a switch auto left on is turned off and one it left off
is turned on (FLIPS: one function per decision). A flip that would not make sense for the data
(NDC rays on cameras that do not face one way) is left out with one line saying why.
"""

import dataclasses

import ml_collections

from nerf_jax.run import auto, config_lib

# The effects auto decides; a representation run keeps auto's values of them.
EFFECT_FIELDS = ("data.background", "train.random_background", "data.ndc", "data.lindisp",
                 "data.contraction", "data.focus", "model.appearance_dims", "eval.appearance",
                 "model.view_dependent", "data.subject", "data.photo_bounds",
                 "data.visual_hull", "data.photo_zoom", "loss.robust.weight", "loss.depth.weight",
                 "train.pose_refinement", "train.intrinsics_refinement",
                 "data.factor")
# The representations auto chooses from (auto.auto_config) and configs/hash.py, the lattice
# it could take instead of fast.py's dense grids; on a GPU, auto.GPU_CONFIGS's counterparts.
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
  """The config name auto chose, from its last decision line ('representation: configs/X.py');
  ValueError where `result` was not decided by auto."""
  lines = [l for l in result.get("auto_decisions", ()) if l.startswith("representation: ")]
  if not lines:
    raise ValueError("the config was not decided by auto (no 'representation:' line in "
                     "auto_decisions): regret measures --config=auto")
  return lines[-1][len("representation: configs/"):-len(".py")]


def has_cones(config):
  """Whether `config` reads cones: the integrated positional encoding, or a lattice's
  anti-aliasing (auto.cone_effects)."""
  encoding = config.model.encoding
  return encoding == "ipe" or (encoding in ("grid", "hash") and
                               bool(config.model[encoding].antialias))


def _cones(result, base, context):
  """Cones off (the representation's own encoding), or on as auto.cone_effects turns them
  on."""
  if has_cones(result):
    return ({"model.encoding": "posenc"} if result.model.encoding == "ipe" else
            {f"model.{result.model.encoding}.antialias": False}), ""
  effects = auto.cone_effects(result)
  if not effects:
    return None, f"model.encoding={result.model.encoding!r} has no cones yet"
  return effects, ""


def _switch(field):
  """A flip of the boolean `field`: its value in auto's result negated."""
  return lambda result, base, context: (
      {field: not bool(config_lib.get_field(result, field))}, "")


def _forward(result, base, context):
  if result.data.ndc:
    return {"data.ndc": False}, ""
  return None, "NDC rays need cameras that face one way (auto found none)"


def _contraction(result, base, context):
  if result.data.ndc:
    return None, "NDC rays take no contraction"
  return {"data.contraction": "" if result.data.contraction else auto.CONTRACTION}, ""


def _focus(result, base, context):
  if not result.data.contraction:
    return None, "the world is centred only where the space beyond is contracted"
  return {"data.focus": not result.data.focus}, ""


def _appearance(result, base, context):
  return {"model.appearance_dims": 0 if result.model.appearance_dims else
          auto.APPEARANCE_DIMS}, ""


def _subject(result, base, context):
  if result.data.subject:
    return {"data.subject": "", "data.photo_bounds": False, "data.visual_hull": False,
            "data.photo_zoom": False}, ""
  return None, "no sparse points or masks marked a subject to fill the inner region"


def _on_subject(field):
  """A flip of `field`, which auto decides only with a subject (data.subject)."""
  def flip(result, base, context):
    if not result.data.subject:
      return None, "decided only with a subject (data.subject)"
    return {field: not bool(config_lib.get_field(result, field))}, ""
  return flip


def _transients(result, base, context):
  """RobustNeRF's trimmed loss off, or on with patches that fit the images (one camera: the
  patch batches need it)."""
  if result.loss.robust.weight > 0:
    return {"loss.robust.weight": 0.0, "train.patch_size": int(base.train.patch_size)}, ""
  if not context["one_camera"]:
    return None, "its patch batches need images of one camera"
  patch = int(min(result.train.patch_size, context["height"], context["width"]))
  return {"loss.robust.weight": 1.0, "train.patch_size": patch}, ""


def _depth(result, base, context):
  """DS-NeRF's depth from the tracks off where auto turned it on (auto.depth_effects)."""
  if result.loss.depth.weight > 0:
    return {"loss.depth.weight": 0.0}, ""
  return None, "auto left the depth from the tracks off (no tracks, or more views than measured)"


def _cameras(result, base, context):
  """The cameras as stored, with the zooms fitted to the masks, where auto refined them with the
  field (auto.camera_effects)."""
  if result.train.intrinsics_refinement:
    return {"train.intrinsics_refinement": False, "train.pose_refinement": False,
            "data.photo_zoom": True}, ""
  return None, "auto did not refine the cameras (no tracks that disagree with one stored camera)"


def _step_rule(result, base, context):
  """Auto's step rule off (auto.by_steps): the effects it waits to decide stay on at any
  budget."""
  if not result.auto_by_steps:
    return None, "auto turned on nothing that pays only from a step count (auto.MIN_STEPS)"
  return {"auto_by_steps": ()}, ""


# decision name -> flip(result, base, context) -> (overrides or None, why none). context:
# {'height', 'width': the training images' pixels, 'one_camera': whether they share one
# camera}.
FLIPS = {
    "background": _switch("train.random_background"),
    "forward": _forward,
    "contraction": _contraction,
    "focus": _focus,
    "appearance": _appearance,
    "view_dependence": _switch("model.view_dependent"),
    "cones": _cones,
    "subject": _subject,
    "photo_bounds": _on_subject("data.photo_bounds"),
    "visual_hull": _on_subject("data.visual_hull"),
    "photo_zoom": _on_subject("data.photo_zoom"),
    "transients": _transients,
    "depth": _depth,
    "cameras": _cameras,
    "pose_refinement": _switch("train.pose_refinement"),
    "step_rule": _step_rule,
}


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
  'gpu'...; auto.for_backend: 'fast' and 'detail' are both 'gpu/lego' there, named 'fast'),
  less `chosen`, in order."""
  names = {}
  for kind in REPRESENTATIONS:
    name = auto.for_backend(kind, backend)[0] if kind in auto.GPU_CONFIGS else kind
    names.setdefault(name, kind)
  return {name: kind for name, kind in names.items() if name != chosen}


def representation_runs(result, chosen, user, backend):
  """([Run] of each other representation that applies, [line] for each that does not).
  Each keeps auto's EFFECT_FIELDS (and its patch size under the trimmed loss, and its step
  rule: auto.by_steps), takes the
  cones auto.cone_effects gives it where `result` reads cones, and the command's `user`
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
    if has_cones(result):
      overrides.update(auto.cone_effects(base))
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
