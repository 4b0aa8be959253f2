"""Auto's step rule (auto.MIN_STEPS, auto.by_steps): an effect that pays only after enough
steps stays on only where the run's step budget holds them. Decided on a given step budget
before the state is built, on a time budget once the calibration has fitted the steps, and a
resumed run keeps what its first part decided (else its checkpoint would not fit)."""

import json
import os

import pytest

from nerf_jax.run import config_lib, train_lib
from nerf_jax.run.auto import auto
from tests.helpers import load_data, small_config

VD = "model.view_dependent"


def _pending(view_dependent=True):
  config = config_lib.load("fast")
  config.model.view_dependent = view_dependent
  config.auto_by_steps = (VD,)
  config.auto_decisions = ("representation: configs/fast.py",)
  return config


def test_an_effect_below_its_steps_is_switched_off_and_the_record_cleared():
  fewest = auto.MIN_STEPS[VD][1]
  decided, lines = auto.by_steps(_pending(), fewest - 1)
  assert decided.model.view_dependent is False and decided.auto_by_steps == ()
  assert lines == [f"step rule: {VD}=False, the run's budget holds {fewest - 1} steps (< the "
                   f"{fewest} from which it pays)"]
  assert decided.auto_decisions == ("representation: configs/fast.py", *lines)


def test_an_effect_from_its_steps_on_is_kept():
  fewest = auto.MIN_STEPS[VD][1]
  pending = _pending()
  decided, lines = auto.by_steps(pending, fewest)
  assert decided.model.view_dependent is True and decided.auto_by_steps == ()
  assert lines[0].endswith(f"holds {fewest} steps (>= the {fewest} from which it pays)")
  assert pending.auto_by_steps == (VD,)  # the argument itself is left as it was


def test_nothing_pending_returns_the_config_itself():
  config = config_lib.load("fast")
  assert auto.by_steps(config, 1) == (config, [])


def _glossy(**fields):
  config = config_lib.load("auto")
  config.data.scene, config.data.image_size, config.data.num_views = "glossy", 24, 40
  for name, value in fields.items():
    config_lib.set_field(config, name, value)
  return config


def test_auto_waits_to_decide_the_view_dependence_it_turns_on(capsys):
  decided = auto.auto_config(_glossy(), load_data(_glossy().data)[0])
  assert decided.model.view_dependent is True and decided.auto_by_steps == (VD,)
  assert any(l.startswith(f"step rule: {VD} kept only where the run's step budget")
             for l in decided.auto_decisions)


def test_a_flag_of_the_users_is_not_waited_on():
  config = _glossy(**{VD: True})
  config.auto_flags = (VD,)
  decided = auto.auto_config(config, load_data(config.data)[0])
  assert decided.model.view_dependent is True and decided.auto_by_steps == ()


def _train(tmp_path, **fields):
  config = small_config({"data.scene": "glossy", "data.image_size": 24, "data.num_views": 40,
                         "render.video_frames": 0, "train.log_every": 1000,
                         "train.checkpoint_every": 1000, **fields}, base="auto")
  train_lib.train_and_evaluate(config, str(tmp_path))
  with open(os.path.join(tmp_path, "config.json")) as f:
    return json.load(f)


def test_a_step_budget_below_the_steps_trains_without_the_effect(tmp_path, capsys):
  saved = _train(tmp_path, **{"train.max_steps": 3})
  assert saved["model"]["view_dependent"] is False and saved["auto_by_steps"] == []
  assert (f"auto: step rule: {VD}=False, the run's budget holds 3 steps"
          in capsys.readouterr().out)


def test_a_time_budget_counts_the_fit_the_effects_step_still_needs():
  assert train_lib.steps_after_another_fit(100, 50.0, 25.0) == 50
  assert train_lib.steps_after_another_fit(100, 50.0, 0.0) == 100
  assert train_lib.steps_after_another_fit(100, 10.0, 20.0) == 0  # no time for another fit


@pytest.mark.parametrize("fewest,kept", [(0, True), (10 ** 9, False)])
def test_a_time_budget_decides_on_its_fitted_steps_and_resumes_so(tmp_path, monkeypatch,
                                                                    capsys, fewest, kept):
  monkeypatch.setitem(auto.MIN_STEPS, VD, (False, fewest))
  saved = _train(tmp_path, **{"train.max_seconds": 4.0})
  assert saved["model"]["view_dependent"] is kept and saved["auto_by_steps"] == []
  steps = saved["train"]["max_steps"]
  assert f"auto: step rule: {VD}={kept}, the run's budget holds " in capsys.readouterr().out
  # Again in the same workdir, with the rule now the other way: the budget is spent, and the
  # run keeps what its first part decided (its config.json), so its checkpoint restores.
  monkeypatch.setitem(auto.MIN_STEPS, VD, (False, 10 ** 9 if kept else 0))
  again = _train(tmp_path, **{"train.max_seconds": 4.0})
  assert again["model"]["view_dependent"] is kept and again["train"]["max_steps"] == steps
  assert again["auto_decisions"] == saved["auto_decisions"]
  out = capsys.readouterr().out
  assert "resuming from" in out and "step rule" not in out.split("resuming from")[1]


@pytest.mark.parametrize("seconds", [0.0, 3.0], ids=["steps", "seconds"])
def test_the_benchmarks_run_decides_as_training_does(monkeypatch, seconds):
  # python -m nerf_jax.bench's run (timed_run.train_and_measure) on auto's config: the effect
  # the rule leaves off is not in the trained model (the view-dependent head's parameters).
  from nerf_jax.bench import timed_run  # pylint: disable=import-outside-toplevel
  options = timed_run.Options(eval_times=(), render_repeats=1, matmul_repeats=1)
  params = {}
  for fewest in (0, 10 ** 9):
    monkeypatch.setitem(auto.MIN_STEPS, VD, (False, fewest))
    config = small_config({"data.scene": "glossy", "data.image_size": 24,
                           "data.num_views": 40, "train.max_steps": 0 if seconds else 2,
                           "train.max_seconds": seconds, "render.video_frames": 0},
                          base="auto")
    params[fewest] = timed_run.train_and_measure(config, options)["params"]
  assert params[10 ** 9] < params[0]
