"""A crash during a checkpoint write: a truncated temporary is ignored and then cleaned, and a
failed final rename leaves the previous checkpoint intact. Randomness is seeded (SEED)."""

import os

import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.train import checkpoints

SEED = 15  # the truncation point and the states are drawn from this: a failure reproduces
SIGNATURE = {"width": 8}


def _state(rng):
  return {"step": np.int32(rng.integers(1000)), "w": rng.normal(size=(4, 8)).astype(np.float32)}


def _equal(a, b):
  return all(np.array_equal(a[k], b[k]) for k in a)


def test_truncated_temporary_is_ignored_by_restore_and_cleaned_by_the_next_save(tmp_path):
  rng = np.random.default_rng(SEED)
  workdir = str(tmp_path)
  first = _state(rng)
  checkpoints.save(workdir, 10, first, SIGNATURE)
  # A run killed while writing step 20: its temporary holds a prefix of a real checkpoint.
  checkpoints.save(str(tmp_path / "other"), 20, _state(rng), SIGNATURE)
  whole = open(checkpoints.latest_path(str(tmp_path / "other")), "rb").read()
  cut = int(rng.integers(1, len(whole)))
  folder = checkpoints.checkpoint_dir(workdir)
  stale = os.path.join(folder, "ckpt_20.msgpack.tmp-999999999")  # a pid that is not ours
  open(stale, "wb").write(whole[:cut])
  assert checkpoints.list_steps(workdir) == [10], cut
  assert checkpoints.latest_path(workdir).endswith("ckpt_10.msgpack")
  assert _equal(checkpoints.restore(checkpoints.latest_path(workdir), first, SIGNATURE), first)
  second = _state(rng)
  checkpoints.save(workdir, 30, second, SIGNATURE)
  assert not os.path.exists(stale), cut
  assert sorted(os.listdir(folder)) == ["ckpt_10.msgpack", "ckpt_30.msgpack"]
  assert _equal(checkpoints.restore(checkpoints.latest_path(workdir), second, SIGNATURE), second)


def test_a_failed_rename_leaves_the_previous_checkpoint_intact(tmp_path, monkeypatch):
  rng = np.random.default_rng(SEED)
  workdir = str(tmp_path)
  first = _state(rng)
  path = checkpoints.save(workdir, 10, first, SIGNATURE, keep=1)
  before = open(path, "rb").read()

  def fail(src, dst):
    raise OSError(28, "No space left on device")
  monkeypatch.setattr(checkpoints.os, "replace", fail)
  with pytest.raises(OSError, match="No space"):
    checkpoints.save(workdir, 20, _state(rng), SIGNATURE, keep=1)
  monkeypatch.undo()
  # The old checkpoint is still the newest, byte for byte, and restores; keep=1 deleted nothing.
  assert checkpoints.list_steps(workdir) == [10]
  assert open(path, "rb").read() == before
  assert _equal(checkpoints.restore(checkpoints.latest_path(workdir), first, SIGNATURE), first)
  # The next save (a resumed run: another process) succeeds and clears the leftover temporary.
  monkeypatch.setattr(checkpoints.os, "getpid", lambda: 4242)
  third = _state(rng)
  checkpoints.save(workdir, 30, third, SIGNATURE, keep=1)
  assert os.listdir(checkpoints.checkpoint_dir(workdir)) == ["ckpt_30.msgpack"]
  assert _equal(checkpoints.restore(checkpoints.latest_path(workdir), third, SIGNATURE), third)


def test_a_setting_only_the_checkpoint_has_is_named(tmp_path):
  # A run saved with an entry (e.g. intrinsics refinement on) resumed by a config that lacks
  # it: the refusal names the entry, on whichever side it is missing.
  state = {"w": jnp.zeros(3)}
  checkpoints.save(str(tmp_path), 1, state, {"width": 64, "intrinsics_refinement": True})
  path = checkpoints.latest_path(str(tmp_path))
  with pytest.raises(checkpoints.CheckpointError,
                     match="intrinsics_refinement: checkpoint True vs config None"):
    checkpoints.restore(path, state, {"width": 64})
