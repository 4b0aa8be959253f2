"""The record of one of auto's rules, and the context each reads (auto.auto_config builds it).

A rule is one module of nerf_jax/run/auto/rules/ defining `RULE = Rule(...)`; rules/__init__.py
orders them (the order of auto's printed lines). docs/auto.md's table holds one row per rule,
keyed by `Rule.row` (tests/topics/test_auto_doc.py checks both ways).
"""

import dataclasses
import functools
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple

import ml_collections

from nerf_jax.run import config_lib


@dataclasses.dataclass
class Context:
  """What the rules read. Built once per auto_config call; `effects` grows as the rules run."""
  config: ml_collections.ConfigDict  # the given config: configs/auto.py and the user's flags
  user: Dict[str, Any]  # {dotted field: value} the user set (they win over the rules)
  photos: Any  # the training Dataset, each photo through its own camera
  dataset: Any  # photos.one_camera(): the views the rules read but the subject's and depth's
  decisions: Optional[Dict[str, Any]]  # {name: characterise.Decision}; None: too few cameras
  backend: str  # jax.default_backend() or the one given: 'cpu', 'gpu', ...
  before_loading: Tuple[dict, list]  # ({field: value}, [line]) decided before loading
  min_steps: Mapping[str, tuple]  # auto.MIN_STEPS of the rules run
  chosen: str = ""  # the representation's config name ('fast', 'gpu/lego', ...)
  result: Optional[ml_collections.ConfigDict] = None  # configs/<chosen>.py as loaded
  backend_line: str = ""  # the line naming the backend and the chosen config
  effects: Dict[str, Any] = dataclasses.field(default_factory=dict)  # decided so far

  def found(self, name):
    """What characterise's rule `name` found (True, False, None: cannot tell); None without
    decisions (too few cameras)."""
    return None if self.decisions is None else self.decisions[name].found

  def reason(self, name):
    """The measured reason line of characterise's rule `name`."""
    return self.decisions[name].reason


def measured(decide):
  """A rule's `decide` that reads characterise's measurements, run only where there are some:
  ({}, []) where the capture has too few cameras to characterise (Context.decisions None: the
  too_few rule's line says so)."""
  @functools.wraps(decide)
  def where_measured(context):
    if context.decisions is None:
      return {}, []
    return decide(context)
  return where_measured


# flip(result, base, context) -> ({field: value} or None, why none): the regret benchmark's
# run of auto's config with the decision turned the other way (bench/regret_plan.py). result:
# auto's ConfigDict; base: the chosen config as loaded; context: {'height', 'width': the training
# images' pixels, 'one_camera': whether they share one camera}.
Flip = Callable[[ml_collections.ConfigDict, ml_collections.ConfigDict, dict],
                Tuple[Optional[dict], str]]


@dataclasses.dataclass(frozen=True)
class Rule:
  """One of auto's rules."""
  name: str  # short name, e.g. 'depth'
  decide: Callable[[Context], Tuple[Dict[str, Any], List[str]]]  # ({field: value}, [line])
  row: str  # its row's key (the 'rule' column) in docs/auto.md's table
  fields: Tuple[str, ...] = ()  # the fields it decides, which another representation keeps
  flips: Mapping[str, Flip] = dataclasses.field(default_factory=dict)  # {flip name: Flip}
  # {field: (its value off, the fewest steps from which it pays)}: the step rule waits on it
  min_steps: Mapping[str, Tuple[Any, int]] = dataclasses.field(default_factory=dict)
  # The representation it calls for (a CPU config name: 'fast', 'llff'...) or None; the first
  # rule that names one chooses it, before any rule decides ('capture' where none does).
  representation: Optional[Callable[[Context], Optional[str]]] = None


def switch_flip(field):
  """The Flip of the boolean `field`: its value in auto's result negated."""
  return lambda result, base, context: (
      {field: not bool(config_lib.get_field(result, field))}, "")
