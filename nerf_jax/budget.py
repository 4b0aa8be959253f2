"""How long a run is: the step budget, and a time budget turned into one.

`train.max_steps` > 0 is the user's step budget. With `train.max_steps = 0` a run with a time
budget (`train.max_seconds` > 0) times a few throwaway steps (`calibrate`) and fits the step budget
and the learning-rate schedule to the steps expected in the time left (`fit_schedule`); the clock
alone then ends it. Without either, `train.default_steps` is the budget.
"""

import time

import jax
import numpy as np

# A time budget's calibration: this long, or this share of the budget if that is less.
CALIBRATION_SECONDS = 3.0
CALIBRATION_SHARE = 0.05


def fits_time(train_config):
  """Whether the step budget and schedule follow from the time budget (max_seconds > 0 and no
  max_steps of the user's)."""
  return train_config.max_seconds > 0 and not train_config.max_steps


def planned_steps(train_config):
  """The steps the schedule spans: max_steps if set, else default_steps."""
  return int(train_config.max_steps or train_config.default_steps)


def fit_schedule(train_config, num_steps):
  """Set max_steps = num_steps (in place); warm-up keeps its share of the planned steps."""
  share = train_config.warmup_steps / max(planned_steps(train_config), 1)
  train_config.warmup_steps = int(round(share * num_steps))
  train_config.max_steps = int(num_steps)


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
