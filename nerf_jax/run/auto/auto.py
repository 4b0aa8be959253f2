"""`--config=auto`: a config decided from the training views by the rules (rules/, in their
order) and the user's flags, which win over the decisions.
"""

import jax
import ml_collections

from nerf_jax.run import config_lib
from nerf_jax.run.auto import characterise
from nerf_jax.run.auto.rule import Context
from nerf_jax.run.auto.rules import RULES, backend as backend_rule

# Effects that pay only after enough steps: {field a rule turns on: (its value off, the fewest
# steps from which it pays)}, the rules' own (Rule.min_steps). Auto leaves one off where the
# run's step budget holds fewer: the steps given, or those a time budget holds with the waiting
# effects off (by_steps, decided once the run knows them).
MIN_STEPS = {field: steps for rule in RULES for field, steps in rule.min_steps.items()}
_OWN = ("auto", "auto_decisions", "auto_flags", "auto_by_steps",
        "auto_representation")  # auto's own fields


def _flat(config):
  """{dotted name: value} of every leaf field of a ConfigDict."""
  out = {}
  def walk(node, prefix):
    for key, value in node.items():
      if isinstance(value, ml_collections.ConfigDict):
        walk(value, f"{prefix}{key}.")
      else:
        out[prefix + key] = tuple(value) if isinstance(value, list) else value
  walk(config, "")
  return out


def context_of(config, dataset, backend, before_loading, rules=RULES):
  """The Context `rules` read: the user's flags, characterise.decide's decisions and the
  representation the first rule that names one chooses ('capture' where none does), on
  `backend` (rules/backend.for_backend)."""
  base = _flat(config_lib.load("auto"))
  user = {k: v for k, v in _flat(config).items()
          if (base.get(k) != v or k in config.auto_flags) and k not in _OWN}
  decisions = characterise.decide(dataset)  # scales from every camera, the rest from image 0's
  context = Context(config, user, dataset, dataset.one_camera(),
                    None if decisions is None else {d.name: d for d in decisions}, backend,
                    before_loading, {f: s for r in rules for f, s in r.min_steps.items()})
  kind = next((name for name in (r.representation(context) for r in rules
                                 if r.representation) if name), "capture")
  context.chosen, context.backend_line = backend_rule.for_backend(kind, backend)
  context.result = config_lib.load(context.chosen)
  return context


def auto_config(config, dataset, backend=None, before_loading=({}, []), rules=RULES):
  """`config` (config.auto: configs/auto.py and the user's flags) decided from the training
  views `dataset` by `rules` (rules.RULES), in order: the representation the first rule that
  names one chooses (Rule.representation; capture.py where none does; on a 'gpu' `backend`,
  default jax.default_backend(), its configs/gpu/ counterpart), then each rule's effects on
  top and its lines. A field the user set (named in config.auto_flags by the command line, or
  differing from configs/auto.py's) wins over the decision, with one line saying so (the
  your_flags rule). Prints the lines, which go to config.auto_decisions (config.json); the
  chosen config's name goes to config.auto_representation, and auto is off in the result (a
  restored run keeps what was decided). before_loading: ({field: value}, [line]) decided
  before `dataset` was loaded (resolution.factor_effects: data.factor; the photo_size rule
  records it first)."""
  context = context_of(config, dataset, backend or jax.default_backend(), before_loading, rules)
  lines = []
  for rule in rules:
    effects, said = rule.decide(context)
    context.effects.update(effects)
    lines += said
  result, effects = context.result, context.effects
  values = {**_flat(result), **effects, **context.user}
  for name, value in values.items():
    if name not in _OWN:
      config_lib.set_field(result, name, value)
  result.auto = False
  result.auto_by_steps = effects.get("auto_by_steps", ())
  result.auto_decisions = tuple(lines)
  result.auto_representation = context.chosen
  for line in lines:
    print(f"auto: {line}", flush=True)
  return result


def by_steps(config, steps):
  """(config, [line]): a copy of `config` with each effect of config.auto_by_steps that pays
  only from more than `steps` steps (MIN_STEPS) off, one line each, and the record cleared
  (decided: config.json keeps the result); `config` itself and [] where nothing is pending.
  steps: int, the run's step budget (given, or fitted to its time budget)."""
  if not config.auto_by_steps:
    return config, []
  out, lines = ml_collections.ConfigDict(config.to_dict()), []
  for name in config.auto_by_steps:
    off, fewest = MIN_STEPS[name]
    keep = steps >= fewest
    if not keep:
      config_lib.set_field(out, name, off)
    lines.append(f"step rule: {name}={config_lib.get_field(out, name)!r}, the run's budget "
                 f"holds {steps} steps ({'>=' if keep else '<'} the {fewest} from which it "
                 "pays)")
  out.auto_by_steps = ()
  out.auto_decisions = (*config.auto_decisions, *lines)
  return out, lines
