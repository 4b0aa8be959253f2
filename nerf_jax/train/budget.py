"""How long a run is: the step budget, and a time budget turned into one.

`train.max_steps` > 0 is the user's step budget. With `train.max_steps = 0` a run with a time
budget (`train.max_seconds` > 0) times a few throwaway steps (`calibrate`) and fits the step budget
and the learning-rate schedule to the steps expected in the time left (`steps_in`;
train_lib.fit_to_time does it for training and the benchmark alike); the clock alone then ends
it. Without either, `train.default_steps` is the budget.
"""

import time

import jax
import numpy as np

# A time budget's calibration: this long, or this share of the budget if that is less.
CALIBRATION_SECONDS = 3.0
CALIBRATION_SHARE = 0.05


def calibrate(step_fn, state, seconds):
  """(seconds per step, compile seconds): step `state` with step_fn (state -> state, may donate
  it) for about `seconds` after a first step that compiles, syncing after every step.
  Returns the median of the timed steps (the first step's time if only it fitted)."""
  start = time.perf_counter()
  state = jax.block_until_ready(step_fn(state))
  compile_seconds = time.perf_counter() - start
  times, end = [], time.perf_counter() + seconds
  while time.perf_counter() < end or not times:
    start = time.perf_counter()
    state = jax.block_until_ready(step_fn(state))
    times.append(time.perf_counter() - start)
  return float(np.median(times)), compile_seconds


def steps_in(seconds_left, step_seconds, compile_seconds):
  """The steps expected in `seconds_left` after one more compile: at least 1."""
  return max(1, int((seconds_left - compile_seconds) / max(step_seconds, 1e-9)))
