"""The live viewer during training (`--config.viewer.enabled=True`): a watcher, which nerf-train
passes to train_lib.train_and_evaluate as `watchers=(start,)`.

Nobody watching costs one call and one boolean test per step. With a browser connected, every
`refresh_s` seconds the step's parameters are copied (they are donated to the next step) and
handed to the viewer's render thread, which draws between and beside the steps.
"""

import time

import jax
import jax.numpy as jnp


class _Off:
  """The watcher when the viewer is off."""

  def after_step(self, step, get_params):
    pass

  def close(self):
    pass


class LiveViewer:
  """Hands the run's parameters to `viewer` (a server.Viewer) while someone watches."""

  def __init__(self, viewer, refresh_s=1.0, clock=time.perf_counter):
    self.viewer, self.refresh_s, self.clock = viewer, refresh_s, clock
    self._last = -float("inf")

  def after_step(self, step, get_params):
    """Called after every step; get_params() -> the current params (on one device)."""
    if not self.viewer.watched() or self.clock() - self._last < self.refresh_s:
      return
    params = jax.block_until_ready(jax.tree_util.tree_map(jnp.copy, get_params()))
    self.viewer.set_params(params, step)
    self._last = self.clock()

  def close(self):
    self.viewer.close()


def start(exp, workdir, enabled=True):
  """The watcher of a run of `exp` (experiment_parts.Experiment) in `workdir`: a LiveViewer
  serving `config.viewer.port` where config.viewer.enabled and `enabled` (train_lib passes
  whether this is process 0), or one doing nothing."""
  config = exp.config
  if not (enabled and config.viewer.enabled):
    return _Off()
  from nerf_jax.viewer import scene, server  # pylint: disable=import-outside-toplevel
  viewer = server.Viewer(scene.from_run(exp), None,
                         port=config.viewer.port, out_dir=workdir, warm_up=False,
                         label="nerf_jax (training)")
  print(f"viewer: open {viewer.url} to watch the training", flush=True)
  return LiveViewer(viewer)
