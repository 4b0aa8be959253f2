"""The training loop (train/loop.py) and its hooks' schedules (train/hooks.py), with a stand-in
step: which hooks run after which step, in what order, and how a run ends."""

import os
import signal

from nerf_jax.train import hooks, loop


class _Spy(hooks.Hook):
  """Records (name, step, final) when due; due every `every` steps and at the final step."""

  def __init__(self, name, every, log):
    self.name, self.every_steps, self.log = name, every, log

  def due(self, end):
    return hooks.every(end.step, self.every_steps) or end.final

  def __call__(self, end):
    self.log.append((self.name, end.step, end.final))

  def close(self):
    self.log.append((self.name, "closed", None))


def _step(state):
  return state + 1, {"loss": 0.0}


def test_hooks_run_in_order_when_due_and_close_in_reverse():
  log = []
  state, step, signum = loop.run(0, _step, [_Spy("a", 2, log), _Spy("b", 3, log)], 0, 6)
  assert (state, step, signum) == (6, 6, None)
  expected = []
  for s in range(1, 7):
    expected += [(name, s, s == 6) for name, k in (("a", 2), ("b", 3)) if s % k == 0 or s == 6]
  assert log == expected + [("b", "closed", None), ("a", "closed", None)]


def test_a_resumed_run_counts_from_its_step_and_the_clock_ends_it_after_the_hooks():
  log = []
  clock = iter([False, False, True])
  state, step, _ = loop.run(10, _step, [_Spy("a", 100, log)], 10, 1000, lambda: next(clock))
  assert (state, step) == (13, 13)
  assert log == [("a", 13, True), ("a", "closed", None)]


def test_a_signal_ends_the_run_after_the_hooks_of_its_step_which_see_final():
  log = []

  def step_fn(state):
    if state == 2:
      os.kill(os.getpid(), signal.SIGTERM)  # handled by the loop: a flag, not an exit
    return _step(state)

  previous = signal.getsignal(signal.SIGTERM)
  state, step, signum = loop.run(0, step_fn, [_Spy("ckpt", 100, log)], 0, 10)
  assert (state, step, signum) == (3, 3, signal.SIGTERM)
  assert log == [("ckpt", 3, True), ("ckpt", "closed", None)]
  assert signal.getsignal(signal.SIGTERM) is previous  # the handler is put back


def test_every_zero_is_never():
  assert not hooks.every(5, 0) and hooks.every(6, 3) and not hooks.every(7, 3)


def test_a_clocked_run_waits_for_all_but_its_newest_steps_before_it_reads_the_clock(monkeypatch):
  # jax dispatches steps ahead of the device; the clock must count steps done. A stand-in for
  # jax.block_until_ready records which step's stats the loop waited for before each clock read.
  waited, reads = [], []
  monkeypatch.setattr(loop.jax, "block_until_ready", lambda stats: waited.append(stats["step"]))
  step_fn = lambda state: (state + 1, {"step": state + 1})
  clock = lambda: reads.append(list(waited)) or len(reads) == 4
  loop.run(0, step_fn, [], 0, 100, clock, in_flight=1)
  assert reads == [[], [1], [1, 2], [1, 2, 3]]  # after step n: steps up to n - 1 done
  waited.clear()
  loop.run(0, step_fn, [], 0, 5)
  assert waited == []  # a step budget: no wait, the device's queue stays full


def test_a_time_budget_keeps_one_step_in_flight_in_training(monkeypatch, tmp_path):
  # train_lib.train_and_evaluate with a time budget (configs/debug.py, max_seconds > 0; its
  # max_steps ends it here, in seconds): each time the run reads its clock, every step but the
  # newest has been waited for by the loop (its stats handed to jax.block_until_ready).
  # pylint: disable-next=import-outside-toplevel
  from nerf_jax.run import train_lib
  from tests.helpers import small_config  # pylint: disable=import-outside-toplevel
  seen = {"in_flight": [], "queued": []}
  dispatched, waited = [], set()
  real_wait, real_run = loop.jax.block_until_ready, loop.run

  def wait(x):
    waited.add(id(x))
    return real_wait(x)

  def recording_run(state, step_fn, hooks_, start, last, out_of_time=lambda: False,
                    in_flight=None):
    def step(state):
      state, stats = step_fn(state)
      dispatched.append(stats)
      return state, stats

    def clock():
      seen["queued"].append(sum(id(s) not in waited for s in dispatched))
      return out_of_time()

    seen["in_flight"].append(in_flight)
    return real_run(state, step, hooks_, start, last, clock, in_flight)

  monkeypatch.setattr(loop.jax, "block_until_ready", wait)
  monkeypatch.setattr(train_lib.loop, "run", recording_run)
  config = small_config({"train.max_steps": 6, "train.max_seconds": 600.0,
                         "train.log_every": 0, "train.checkpoint_every": 0,
                         "render.video_frames": 0})
  train_lib.train_and_evaluate(config, str(tmp_path))
  assert seen["in_flight"] == [1]
  assert len(seen["queued"]) >= 4 and set(seen["queued"]) == {1}
