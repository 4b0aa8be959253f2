"""The train state: what a checkpoint holds and the train step updates, and the upgrade of
states saved by earlier versions (the config's side of a checkpoint: run/signature.py)."""

import flax.struct
import jax.numpy as jnp
import optax


@flax.struct.dataclass
class TrainState:
  step: jnp.ndarray  # int32 [], steps taken
  params: dict  # trained: {'coarse': ..., ['fine': ...]}
  opt_state: optax.OptState
  bad_step: jnp.ndarray  # int32 [], first step whose loss or gradient was non-finite, -1 if none
  buffers: dict = flax.struct.field(default_factory=dict)  # not trained: {['occupancy': grid]}
  # With train.ema_decay: {'params': the moving average of params}, else {}.
  ema: dict = flax.struct.field(default_factory=dict)

  @property
  def variables(self):
    """What the renderers take: {'params': ..., **buffers} (render/renderer.py), with the
    weights' moving average as the params when the run keeps one (scores, renders, viewer)."""
    return {"params": self.ema.get("params", self.params), **self.buffers}

  @property
  def training_variables(self):
    """{'params': the trained params, **buffers}: what the train step itself renders with."""
    return {"params": self.params, **self.buffers}


def upgrade_state_dict(state):
  """A saved TrainState dict (checkpoints.py) of an earlier version made current: the
  occupancy grid once lived in params['occupancy'] (with Adam moments that stayed zero); it
  now lives in buffers. States saved before train.ema_decay existed hold no 'ema' ({})."""
  if "ema" not in state:
    state = dict(state, ema={})
  if "buffers" in state:
    return state
  state = dict(state, params=dict(state["params"]), buffers={})
  if "occupancy" in state["params"]:
    state["buffers"]["occupancy"] = state["params"].pop("occupancy")
  state["opt_state"] = _without_occupancy(state["opt_state"])
  return state


def _without_occupancy(tree):
  """`tree` (nested dicts) without the 'occupancy' entry of any dict that holds 'coarse'."""
  if not isinstance(tree, dict):
    return tree
  return {k: _without_occupancy(v) for k, v in tree.items()
          if not (k == "occupancy" and "coarse" in tree)}
