"""The progress display: a redrawn bar on a terminal, sparse plain lines elsewhere, a fair ETA."""

import io
import json

import pytest

from nerf_jax.train import progress
from nerf_jax.run import train_lib
from tests.helpers import small_config


class Clock:
  def __init__(self):
    self.now = 0.0

  def __call__(self):
    return self.now


class Tty(io.StringIO):
  def isatty(self):
    return True


def test_plain_lines_only_every_interval_and_a_final_one():
  clock, out = Clock(), io.StringIO()
  bar = progress.Progress(100, "work", stream=out, interval=10.0, clock=clock)
  for i in range(100):
    clock.now += 1.0
    bar.update()
  bar.close()
  lines = out.getvalue().splitlines()
  assert len(lines) == 10  # at t = 10, 20, ..., 100 s; the last one is the final state
  assert lines[-1].startswith("work 100/100 100%")
  assert "\r" not in out.getvalue() and "[" not in lines[0]


def test_written_lines_reset_the_heartbeat_and_close_does_not_repeat():
  clock, out = Clock(), io.StringIO()
  bar = progress.Progress(10, "train", stream=out, interval=5.0, clock=clock)
  for step in range(1, 11):
    clock.now += 1.0
    bar.update(step)
    if step % 4 == 0 or step == 10:
      bar.write(f"step {step}")
  bar.close()
  lines = out.getvalue().splitlines()
  # Heartbeats only when nothing was printed for 5 s; the last written line is the final state.
  assert lines == ["step 4", "step 8", "step 10"], lines


def test_eta_ignores_the_slow_first_item():
  clock = Clock()
  bar = progress.Progress(11, stream=io.StringIO(), clock=clock)
  clock.now = 100.0  # the first item compiles for 100 s
  bar.update()
  assert bar.eta() is None
  for _ in range(5):
    clock.now += 1.0
    bar.update()
  assert bar.eta() == 5.0  # 5 items left at 1 s each
  assert bar.line().endswith("1:45<0:05")


def test_resumed_count_and_terminal_bar():
  clock, out = Clock(), Tty()
  bar = progress.Progress(200, "train", start=100, stream=out, clock=clock)
  clock.now = 1.0
  bar.update(150, info="loss 0.1")
  bar.write("a line that stays")
  bar.close()
  text = out.getvalue()
  assert "\r\033[Ktrain 150/200 [###############-----]  75% loss 0.1" in text
  assert "a line that stays\n" in text and text.endswith("\n")


def test_track_and_format_seconds():
  out = io.StringIO()
  assert list(progress.track(range(3), desc="x", stream=out)) == [0, 1, 2]
  assert out.getvalue().splitlines()[-1].startswith("x 3/3 100%")
  assert progress.format_seconds(59.9) == "0:59"
  assert progress.format_seconds(3725) == "1:02:05"


def test_rate_window_leaves_out_excluded_work_and_restarts():
  clock = Clock()
  window = progress.RateWindow(count=10, clock=clock)
  clock.now += 2.0  # 40 items of training in 2 s
  with window.excluded():
    clock.now += 6.0  # an evaluation: not training
  assert window.rate(50) == 20.0  # 40 items / 2 s, not / 8 s
  clock.now += 4.0  # the next window starts at the last read: 40 more items in 4 s
  assert window.rate(90) == 10.0


class _RecordingWindow(progress.RateWindow):
  """A RateWindow that records its calls: ('rate', count) and ('excluded',)."""
  calls = []

  def rate(self, count):
    self.calls.append(("rate", int(count)))
    return super().rate(count)

  def excluded(self):
    self.calls.append(("excluded",))
    return super().excluded()


@pytest.mark.slow  # trains
def test_training_times_its_windows_without_evaluations_and_checkpoints(tmp_path, monkeypatch):
  # Each log line reads the window once, and every evaluation and checkpoint runs inside
  # `excluded()`, so the rays/s of a window that holds one is the training rate alone.
  monkeypatch.setattr(progress, "RateWindow", _RecordingWindow)
  _RecordingWindow.calls = []
  config = small_config({"train.max_steps": 40, "train.log_every": 10, "train.eval_every": 20,
                         "train.eval_views": 1, "train.checkpoint_every": 20})
  train_lib.train_and_evaluate(config, str(tmp_path))
  calls = _RecordingWindow.calls
  assert [c for c in calls if c[0] == "rate"] == [("rate", s) for s in (10, 20, 30, 40)]
  # Steps 20 and 40: an evaluation, then a checkpoint, each excluded, after that step's rate.
  after = lambda step: calls[calls.index(("rate", step)) + 1:][:2]
  assert after(20) == after(40) == [("excluded",), ("excluded",)]
  records = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
  assert all(r["rays_per_second"] > 0 for r in records if "rays_per_second" in r)
