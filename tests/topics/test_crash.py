"""Crash-safe training: SIGKILL at a random moment, then SIGTERM, then resume = one clean run."""

import json
import os
import random
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

from nerf_jax import cli
from nerf_jax.train import checkpoints
from nerf_jax.run import train_lib
from tests.helpers import params_equal, restored_variables
from tests.helpers import small_config

from tests.helpers import ROOT
STEPS, EVERY = 120, 10
SEED = 15  # draws the kill moment: a failure reproduces with the same delay


# The run: the debug config with these fields (in this process: small_config(RUN)).
RUN = {"train.max_steps": STEPS, "train.checkpoint_every": EVERY, "train.log_every": 50,
       "train.keep_checkpoints": 3, "render.after_training": False}


def _start(workdir):
  """train.py with the flags that make small_config(RUN), in the background."""
  args = [sys.executable, "train.py", "--config=configs/debug.py", f"--workdir={workdir}",
          *[f"--config.{field}={value}" for field, value in RUN.items()]]
  return subprocess.Popen(args, cwd=ROOT, env=dict(os.environ, PYTHONPATH=ROOT),
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def _wait_for_checkpoint_after(workdir, step, proc, timeout=240):
  deadline = time.monotonic() + timeout
  while time.monotonic() < deadline:
    steps = checkpoints.list_steps(workdir)
    if steps and steps[-1] > step:
      return steps[-1]
    assert proc.poll() is None, f"the run ended early: {proc.stderr.read()[-2000:]}"
    time.sleep(0.002)
  raise AssertionError("no checkpoint appeared")


def _terminate_after_checkpoint(workdir, step):
  """SIGTERM this process once `workdir` has a checkpoint after `step`, while the trainer's
  handler is installed (never the default handler, which would end pytest)."""
  deadline = time.monotonic() + 240
  while time.monotonic() < deadline:
    steps = checkpoints.list_steps(workdir)
    if steps and steps[-1] > step and signal.getsignal(signal.SIGTERM) not in (
        signal.SIG_DFL, None):
      os.kill(os.getpid(), signal.SIGTERM)
      return
    time.sleep(0.002)


@pytest.mark.slow  # a training process, killed at a moment of the wall clock
def test_killed_then_stopped_then_resumed_run_matches_an_uninterrupted_one(tmp_path, capsys):
  workdir = str(tmp_path / "crashy")
  # 1. SIGKILL at a random moment after the first checkpoint: no chance to clean up.
  proc = _start(workdir)
  first = _wait_for_checkpoint_after(workdir, 0, proc)
  start = time.monotonic()
  second = _wait_for_checkpoint_after(workdir, first, proc)
  per_step = (time.monotonic() - start) / (second - first)
  delay = random.Random(SEED).uniform(0.0, 0.5 * (STEPS - second) * per_step)  # first half left
  time.sleep(delay)
  proc.kill()
  proc.communicate()
  assert proc.returncode == -signal.SIGKILL, f"finished before the kill ({delay:.2f} s)"
  killed_at = checkpoints.list_steps(workdir)[-1]
  assert 0 < killed_at < STEPS

  # 2. Resume (in this process); SIGTERM it once it has checkpointed again: it saves where it
  #    stands and exits with status 130.
  thread = threading.Thread(target=_terminate_after_checkpoint, args=(workdir, killed_at))
  thread.start()
  capsys.readouterr()
  with pytest.raises(SystemExit) as info:
    cli.run_main(lambda: train_lib.train_and_evaluate(small_config(RUN), workdir))
  thread.join()
  err = capsys.readouterr().err
  assert info.value.code == 130, err
  match = re.search(r"interrupted: stopped by signal 15 at step (\d+); checkpoint saved", err)
  assert match, err
  stopped_at = int(match.group(1))
  assert killed_at < stopped_at < STEPS and checkpoints.list_steps(workdir)[-1] == stopped_at

  # 3. Resume to the end and compare with an uninterrupted run of the same seed.
  resumed = train_lib.train_and_evaluate(small_config(RUN), workdir)
  clean = train_lib.train_and_evaluate(small_config(RUN), str(tmp_path / "clean"))
  assert resumed["steps"] == clean["steps"] == STEPS
  for key in ("psnr", "ssim", "per_view"):
    assert resumed[key] == clean[key], key
  saved = json.loads(open(os.path.join(workdir, "metrics.json")).read())
  assert saved["per_view"] == clean["per_view"]
  assert params_equal(restored_variables(workdir), restored_variables(tmp_path / "clean"))
  assert len(checkpoints.list_steps(workdir)) <= 3  # keep_checkpoints
