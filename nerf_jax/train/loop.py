"""The training loop: a step, then the hooks (nerfstudio's engine/trainer.py with its callbacks).

The loop reads no config and knows no workdir. It takes the jitted step and a list of hooks
(train/hooks.py: the log record, evaluation, the metrics file, TensorBoard, the progress line,
checkpoints, the live viewer), each of which decides after every step whether it is due and
does one thing there; run/train_lib.py builds them from the config.

A hook has `due(end) -> bool`, `__call__(end)` and `close()`; `end` is the StepEnd of the step
just taken. Hooks run in their list's order (a log step's record is filled by the hooks after
`hooks.Record`) and close in the reverse order.
"""

import collections
import dataclasses
import functools
import signal
from typing import Any, Callable, Optional

import jax


class StopRequest:
  """Turns SIGINT/SIGTERM into a flag the loop checks, so the run saves before it exits."""

  def __init__(self):
    self.signum = None

  def __enter__(self):
    self._old = {s: signal.signal(s, self._handle) for s in (signal.SIGINT, signal.SIGTERM)}
    return self

  def _handle(self, signum, frame):
    self.signum = signum

  def __exit__(self, *exc):
    for s, handler in self._old.items():
      signal.signal(s, handler)


@dataclasses.dataclass
class StepEnd:
  """What the hooks see after a step.

  step: the steps taken. state: the TrainState after this one (replicated on the mesh, if any).
  stats: the step's stats, device arrays (hooks.Record fetches them).
  last_step: the run's planned last step (sys.maxsize when the clock ends it).
  out_of_time: () -> whether the run's time is up, asked once, by the first hook that asks.
  stop: the StopRequest of the loop (its signum is set once a signal arrived).
  record: on a log step, the record hooks.Record starts and the later hooks fill; else None.
  extra: on a log step, the stats besides loss and colour/psnr ({name: float}).
  rays_per_second: on a log step, the training rate since the previous log step.
  """
  step: int
  state: Any
  stats: dict
  last_step: int
  out_of_time: Callable[[], bool]
  stop: StopRequest
  record: Optional[dict] = None
  extra: dict = dataclasses.field(default_factory=dict)
  rays_per_second: float = 0.0

  @functools.cached_property
  def last(self):
    """Whether the run ends after this step: its last step, or its time is up."""
    return self.step == self.last_step or self.out_of_time()

  @property
  def final(self):
    """Whether nothing follows this step: `last`, or a signal asked the run to stop."""
    return self.last or self.stop.signum is not None


def run(state, step_fn, hooks, start_step, last_step, out_of_time=lambda: False,
        in_flight=None):
  """Take steps `state = step_fn(state)` after `start_step` until `last_step` or until
  out_of_time() says so after a step, calling the hooks after each; then close them.

  step_fn: state -> (state, stats), the jitted step with its data and key bound.
  in_flight: None, or the most steps left queued on the device after each step (the loop
  waits for the older ones' stats): a clock then counts steps done. Unbounded, jax's
  asynchronous dispatch queues steps ahead of the device, and a time budget ran over by the
  queue (40 steps, 25 s of a 100 s budget, measured on a CPU: docs/regret.md).
  Returns (state, steps taken, signal number or None): with a signal (SIGINT, SIGTERM) the loop
  ends after the hooks of the step it arrived in, which see `final` (a checkpoint hook saves).
  """
  step, queued = start_step, collections.deque()
  with StopRequest() as stop:
    while step < last_step:
      state, stats = step_fn(state)
      step += 1
      if in_flight is not None:
        queued.append(stats)
        while len(queued) > in_flight:
          jax.block_until_ready(queued.popleft())
      end = StepEnd(step, state, stats, last_step, out_of_time, stop)
      for hook in hooks:
        if hook.due(end):
          hook(end)
      if end.final:
        break
  for hook in reversed(hooks):
    hook.close()
  return state, step, stop.signum
