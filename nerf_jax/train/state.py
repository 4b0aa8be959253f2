"""The train state: what a checkpoint holds and the train step updates."""

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
