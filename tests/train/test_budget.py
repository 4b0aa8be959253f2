"""A time budget means the time: train.max_seconds alone sets the run's length, its step budget
and its learning-rate schedule; an explicit train.max_steps still caps it; a resumed run keeps
the schedule it fitted."""

import json
import os
import re

import numpy as np
import pytest

from nerf_jax.run import builders, config_lib, experiment
from nerf_jax.train import optimizer
from nerf_jax.train import budget, checkpoints
from nerf_jax.run import train_lib
from tests.helpers import shipped_configs
from tests.helpers import small_config


def _saved_train(workdir):
  return config_lib.load_saved(str(workdir)).train


def test_the_schedule_spans_the_planned_steps_and_stays_at_lr_final():
  config = small_config({"train.lr": 1e-2, "train.lr_final": 1e-4, "train.warmup_steps": 10})
  tc = config.train
  assert tc.max_steps == 0 and builders.schedule_steps(tc) == tc.default_steps == 20
  train_lib.fit_schedule(tc, 200)  # warm-up keeps its half of the run
  assert (tc.max_steps, tc.warmup_steps) == (200, 100)
  schedule = optimizer.make_schedule(builders.optimizer_settings(config))
  np.testing.assert_allclose([schedule(50), schedule(100), schedule(200), schedule(400)],
                             [5e-3, 1e-2, 1e-4, 1e-4], rtol=1e-5)


def _warm(config, tmp_path):
  """Train `config` once in a throwaway workdir: the step is compiled (and cached for an equal
  config in this process), so the measured run's clock is not mostly compilation on a loaded
  CPU (which a budget of seconds cannot absorb)."""
  train_lib.train_and_evaluate(config, str(tmp_path / "warm"))


@pytest.mark.slow  # wall-clock
def test_max_seconds_alone_trains_for_that_long(tmp_path):
  seconds = 4.0
  _warm(small_config({"train.max_seconds": seconds}), tmp_path)
  result = train_lib.train_and_evaluate(small_config({"train.max_seconds": seconds}),
                                        str(tmp_path / "run"))
  assert seconds <= result["train_seconds"] < seconds + 3.0  # one step and the last checkpoint
  fitted = _saved_train(tmp_path / "run")
  assert fitted.max_steps > 0 and fitted.max_seconds == seconds  # the schedule it used
  assert result["steps"] > fitted.default_steps  # the config's fallback did not cap it
  assert 0.3 < result["steps"] / fitted.max_steps < 3.0  # the schedule spans about the run


@pytest.mark.slow  # wall-clock
def test_an_explicit_max_steps_still_caps_a_time_budget(tmp_path):
  result = train_lib.train_and_evaluate(
      small_config({"train.max_steps": 5, "train.max_seconds": 60.0}), str(tmp_path / "capped"))
  assert result["steps"] == 5 and result["train_seconds"] < 60.0
  result = train_lib.train_and_evaluate(small_config({"train.default_steps": 7}),
                                        str(tmp_path / "steps"))
  assert result["steps"] == 7 and _saved_train(tmp_path / "steps").max_steps == 0


@pytest.mark.slow  # wall-clock
def test_a_resumed_time_budget_run_keeps_its_schedule(tmp_path, monkeypatch):
  config = lambda: small_config({"train.max_seconds": 4.0, "train.checkpoint_every": 5,
                                 "train.log_every": 1000})
  _warm(config(), tmp_path)
  workdir = str(tmp_path / "run")
  first = train_lib.train_and_evaluate(config(), workdir)
  fitted = _saved_train(workdir).max_steps
  steps = checkpoints.list_steps(workdir)
  assert steps[-1] == first["steps"] and len(steps) == 2
  os.remove(checkpoints.latest_path(workdir))  # "killed" after steps[0]

  def no_calibration(*args):
    raise AssertionError("a resumed run must not fit a new schedule")
  monkeypatch.setattr(budget, "calibrate", no_calibration)
  resumed = train_lib.train_and_evaluate(config(), workdir)
  assert resumed["steps"] > steps[0]
  assert _saved_train(workdir).max_steps == fitted
  _, _, meta = experiment.restore(workdir, with_meta=True)
  assert meta["schedule_steps"] == fitted and meta["wall_seconds"] >= 4.0
  with open(os.path.join(workdir, "metrics.json")) as f:
    assert json.load(f)["steps"] == resumed["steps"]


class _Clock:
  """Stands in for budget.time: perf_counter() returns `now`, which the fake step advances."""

  def __init__(self):
    self.now = 0.0

  def perf_counter(self):
    return self.now


def test_fit_to_time_fits_the_steps_of_the_time_left_and_keeps_the_warmup_share(monkeypatch):
  """A step of known time (compiling: 2 s, then 0.5 s with one 5 s outlier) on a budget of
  100 s: calibration runs min(3 s, 5% of 100 s) = 3 s of steps and takes their median (the
  outlier does not count), the time left is asked for with the compile time, and the steps that
  fit in it are the schedule's."""
  clock = _Clock()
  monkeypatch.setattr(budget, "time", clock)
  durations = iter([2.0, 0.5, 0.5, 5.0] + [0.5] * 100)
  calls = []

  def fake_step(state, data, key, planned_steps):
    calls.append(int(planned_steps))
    clock.now += next(durations)
    return state, {}

  asked = []

  def seconds_left(compile_seconds):
    asked.append(compile_seconds)
    return 100.0 - clock.now

  exp = experiment.setup(small_config({"train.max_seconds": 100.0, "train.warmup_steps": 10}))
  config = train_lib.fit_to_time(exp, fake_step, None, None, seconds_left)
  # Brute force: 2 s compile; timed steps until 3 s have passed after it.
  timed, t = [], 2.0
  for d in [0.5, 0.5, 5.0] + [0.5] * 100:
    if t >= 2.0 + 3.0 and timed:
      break
    timed.append(d)
    t += d
  assert asked == [2.0] and len(calls) == 1 + len(timed)
  expected = int((100.0 - t) / np.median(timed))
  assert np.median(timed) == 0.5 and expected == 184
  assert config.train.max_steps == expected
  # Warm-up keeps its share of the config's planned steps: 10 of default_steps 20.
  assert config.train.warmup_steps == round(10 / 20 * expected)
  assert exp.config.train.max_steps == 0 and exp.config.train.warmup_steps == 10  # a copy


def test_fit_to_time_gives_at_least_one_step(monkeypatch):
  clock = _Clock()
  monkeypatch.setattr(budget, "time", clock)

  def slow_step(state, data, key, planned_steps):
    clock.now += 50.0
    return state, {}

  exp = experiment.setup(small_config({"train.max_seconds": 10.0}))
  config = train_lib.fit_to_time(exp, slow_step, None, None, lambda c: 10.0 - clock.now)
  assert config.train.max_steps == 1


@pytest.mark.slow  # wall-clock
def test_a_time_budget_runs_log_lines_count_time_not_the_fitted_steps(tmp_path, monkeypatch,
                                                                      capsys):
  """The fitted step count is an estimate a run may outlast (here: fitted to 1 step); its log
  lines must not show `step N/M` with N > M: the total they show is the time budget."""
  config = lambda: small_config({"train.max_seconds": 4.0})
  _warm(config(), tmp_path)  # so that the run itself has time for many steps
  monkeypatch.setattr(budget, "steps_in", lambda *args: 1)
  capsys.readouterr()
  result = train_lib.train_and_evaluate(config(), str(tmp_path / "run"))
  assert _saved_train(tmp_path / "run").max_steps == 1 < result["steps"]  # outlasted
  lines = [re.match(r"step (\d+)(?:/(\d+))? ", l) for l in capsys.readouterr().out.splitlines()]
  logged = [(int(m.group(1)), m.group(2) and int(m.group(2))) for m in lines if m]
  assert len(logged) >= 2 and logged[-1][0] == result["steps"], logged
  assert all(total is None or step <= total for step, total in logged), logged


@pytest.mark.parametrize("name", shipped_configs())
def test_no_shipped_config_pins_max_steps(name):
  # Otherwise --config.train.max_seconds alone would be capped by the config's step count.
  assert config_lib.load(name).train.max_steps == 0
